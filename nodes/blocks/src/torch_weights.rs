//! Loading a PyTorch state dict (`.pth`, or the same as `.safetensors`) into a Burn module,
//! with key renames, refusing a file in which any of the module's tensors is missing or of
//! another shape: pretrained feature networks (FID's Inception, the perceptual loss's VGG16)
//! must never run partly random.

use std::path::Path;

use burn::module::Module;
use burn::store::{ModuleSnapshot, PyTorchToBurnAdapter, PytorchStore, SafetensorsStore};

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum TorchLoadError {
    #[error("file not found")]
    NotFound,
    #[error("unknown extension (accepted: .pth, .pt, .bin for PyTorch; .safetensors)")]
    UnknownFormat,
    #[error("{0}")]
    Load(String),
    #[error("{count} tensors missing, e.g. {examples}")]
    Missing { count: usize, examples: String },
}

/// Loads `module`'s tensors from `path`, renaming keys with `(regex, replacement)` pairs.
pub fn load_torch_state_dict<M: Module>(
    mut module: M,
    path: &Path,
    remaps: &[(&str, &str)],
) -> Result<M, TorchLoadError> {
    if !path.is_file() {
        return Err(TorchLoadError::NotFound);
    }
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let load = |e: &dyn std::fmt::Display| TorchLoadError::Load(e.to_string());
    let result = match extension.as_str() {
        "pth" | "pt" | "bin" => {
            let mut store = PytorchStore::from_file(path).allow_partial(true);
            for &(from, to) in remaps {
                store = store.with_key_remapping(from, to);
            }
            module.load_from(&mut store).map_err(|e| load(&e))?
        }
        "safetensors" => {
            let mut store = SafetensorsStore::from_file(path)
                .with_from_adapter(PyTorchToBurnAdapter)
                .allow_partial(true);
            for &(from, to) in remaps {
                store = store.with_key_remapping(from, to);
            }
            module.load_from(&mut store).map_err(|e| load(&e))?
        }
        _ => return Err(TorchLoadError::UnknownFormat),
    };
    if !result.errors.is_empty() {
        let first: Vec<String> = result
            .errors
            .iter()
            .take(3)
            .map(|e| format!("{e:?}"))
            .collect();
        return Err(TorchLoadError::Load(format!(
            "{} tensors did not fit: {}",
            result.errors.len(),
            first.join("; ")
        )));
    }
    if !result.missing.is_empty() {
        let examples: Vec<&str> = result
            .missing
            .iter()
            .take(3)
            .map(|(n, _)| n.as_str())
            .collect();
        return Err(TorchLoadError::Missing {
            count: result.missing.len(),
            examples: examples.join(", "),
        });
    }
    Ok(module)
}
