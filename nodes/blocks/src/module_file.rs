//! Module weights on disk, as burnpack files: written whole, and loaded only when every tensor
//! of the module is in the file with the right shape. A missing file, another model's weights,
//! or a config that does not fit the file are errors that say which.

use std::path::{Path, PathBuf};

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use burn::store::{BurnpackStore, ModuleSnapshot};

#[derive(Debug, thiserror::Error)]
pub enum ModuleFileError {
    #[error("{what} weights {path}: file not found")]
    NotFound { what: String, path: PathBuf },
    #[error("{what} weights {path}: {message}")]
    Io {
        what: String,
        path: PathBuf,
        message: String,
    },
    #[error(
        "{what} weights {path} do not fit the config '{config}': {count} tensors missing or of \
         another shape, e.g. {examples}"
    )]
    Mismatch {
        what: String,
        path: PathBuf,
        config: String,
        count: usize,
        examples: String,
    },
    #[error(
        "{what} weights {path}: tensor `{tensor}` holds {count} non-finite values (NaN or Inf); \
         weights like these render black images and forecast nothing"
    )]
    NonFinite {
        what: String,
        path: PathBuf,
        tensor: String,
        count: usize,
    },
}

/// The first float tensor of a module holding a NaN or an infinity, by its path (the path
/// is kept as burn's own store keeps it, from the modules entered).
struct FirstNonFinite {
    path: Vec<String>,
    found: Option<(String, usize)>,
}

impl ModuleVisitor for FirstNonFinite {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_string());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.found.is_some() {
            return;
        }
        let count = param
            .val()
            .to_data()
            .iter::<f32>()
            .filter(|v| !v.is_finite())
            .count();
        if count > 0 {
            self.found = Some((self.path.join("."), count));
        }
    }
}

/// The path of the first float tensor of `module` that holds a non-finite value, with how
/// many it holds.
pub fn first_non_finite<M: Module>(module: &M) -> Option<(String, usize)> {
    let mut visitor = FirstNonFinite {
        path: Vec::new(),
        found: None,
    };
    module.visit(&mut visitor);
    visitor.found
}

/// Writes `module`'s weights as burnpack (the file name is used as given), whole or not at
/// all: into a temporary beside `path` (`bevworld_atomic_file`), then renamed over it. `what`
/// names the model in errors ("tokenizer").
pub fn save_module<M: Module>(module: &M, what: &str, path: &Path) -> Result<(), ModuleFileError> {
    let failed = |message: String| ModuleFileError::Io {
        what: what.into(),
        path: path.to_path_buf(),
        message,
    };
    let temporary = bevworld_atomic_file::temporary_path(path);
    let mut store = BurnpackStore::from_file(&temporary)
        .auto_extension(false)
        .overwrite(true);
    if let Err(error) = module.save_into(&mut store) {
        let _ = std::fs::remove_file(&temporary);
        return Err(failed(error.to_string()));
    }
    std::fs::rename(&temporary, path).map_err(|e| failed(e.to_string()))
}

/// Loads every tensor of `module` (built for the config named `config`) from `path`; a missing
/// tensor or one of another shape is an error naming a few of them.
pub fn load_module<M: Module>(
    mut module: M,
    what: &str,
    config: &str,
    path: &Path,
) -> Result<M, ModuleFileError> {
    if !path.is_file() {
        return Err(ModuleFileError::NotFound {
            what: what.into(),
            path: path.to_path_buf(),
        });
    }
    check_header(what, path)?;
    let mut store = BurnpackStore::from_file(path)
        .auto_extension(false)
        .allow_partial(true)
        // Collect shape errors into the result, to name a few instead of all of them.
        .validate(false);
    let result = module
        .load_from(&mut store)
        .map_err(|e| ModuleFileError::Io {
            what: what.into(),
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    let mut problems: Vec<String> = result
        .missing
        .iter()
        .map(|(name, _)| format!("{name} (missing)"))
        .collect();
    problems.extend(result.errors.iter().map(|e| format!("{e:?}")));
    if problems.is_empty() {
        match first_non_finite(&module) {
            Some((tensor, count)) => Err(ModuleFileError::NonFinite {
                what: what.into(),
                path: path.to_path_buf(),
                tensor,
                count,
            }),
            None => Ok(module),
        }
    } else {
        Err(ModuleFileError::Mismatch {
            what: what.into(),
            path: path.to_path_buf(),
            config: config.to_string(),
            count: problems.len(),
            examples: problems
                .iter()
                .take(3)
                .cloned()
                .collect::<Vec<_>>()
                .join("; "),
        })
    }
}

/// Reads a burnpack file's fixed header and checks that the metadata it announces fits in the
/// file, before burn's reader allocates the announced size: one flipped bit in that length
/// would otherwise ask for up to burn's 100 MiB cap for a file of a few kilobytes.
fn check_header(what: &str, path: &Path) -> Result<(), ModuleFileError> {
    use burn::store::burn_pack::{HEADER_SIZE, Header};
    use std::io::Read;
    let io = |message: String| ModuleFileError::Io {
        what: what.into(),
        path: path.to_path_buf(),
        message,
    };
    let mut file = std::fs::File::open(path).map_err(|e| io(format!("cannot read ({e})")))?;
    let length = file
        .metadata()
        .map_err(|e| io(format!("cannot read ({e})")))?
        .len();
    let mut bytes = [0u8; HEADER_SIZE];
    file.read_exact(&mut bytes).map_err(|_| {
        io(format!(
            "not a burnpack weights file ({length} bytes, shorter than its {HEADER_SIZE}-byte header)"
        ))
    })?;
    let header =
        Header::from_bytes(&bytes).map_err(|e| io(format!("not a burnpack weights file ({e})")))?;
    let room = length.saturating_sub(HEADER_SIZE as u64);
    if u64::from(header.metadata_size) > room {
        return Err(io(format!(
            "not a burnpack weights file: its header announces {} bytes of metadata, but only {room} follow",
            header.metadata_size
        )));
    }
    Ok(())
}

/// Checks, without loading any tensor, that `path` is a readable burnpack file holding
/// tensors: its header and metadata only are read. What `bevworld check` can say of a weights
/// file; whether the tensors fit a config is found when they load.
pub fn check_file(what: &str, path: &Path) -> Result<(), ModuleFileError> {
    if !path.is_file() {
        return Err(ModuleFileError::NotFound {
            what: what.into(),
            path: path.to_path_buf(),
        });
    }
    let io = |message: String| ModuleFileError::Io {
        what: what.into(),
        path: path.to_path_buf(),
        message,
    };
    check_header(what, path)?;
    let reader = burn::store::burn_pack::Reader::from_file_exact(path)
        .map_err(|e| io(format!("not a burnpack weights file ({e})")))?;
    if reader.tensor_names().is_empty() {
        return Err(io("holds no tensors".into()));
    }
    Ok(())
}
