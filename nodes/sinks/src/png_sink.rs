//! `png_sink`: writes each image of an `ImageSet` as an 8-bit RGB PNG,
//! `<out>/<frame:06>/<name><suffix>.png`.

use std::io::Cursor;
use std::path::PathBuf;

use bevworld_graph::io::{FolderClaim, safe_file_name};
use bevworld_graph::{Inputs, KindSpec, Node, NodeError, ParamError, Port, Registry, Sink};
use bevworld_types::ImageSet;
use image::ImageFormat;
use serde::{Deserialize, Serialize};

use crate::writes::Writes;

// The node's ports, each named once (`bevworld_graph::Port`).
const IMAGES: Port<ImageSet> = Port::new("images");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PngSinkParams {
    /// Output folder; one sub-folder per frame.
    pub out: PathBuf,
    /// Appended to each image name, e.g. `_recon`.
    #[serde(default)]
    pub suffix: String,
}

pub struct PngSink {
    params: PngSinkParams,
    writes: Writes,
    /// The output folder, held for this run (`FolderClaim`).
    _claim: Option<FolderClaim>,
}

impl Sink for PngSink {
    fn start(&mut self) -> Result<(), NodeError> {
        self._claim = Some(FolderClaim::acquire(&self.params.out).map_err(NodeError::fatal)?);
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let set = inputs.get(&IMAGES)?;
        let frame = inputs.header().map(|h| h.seq).unwrap_or(0);
        let folder = self.params.out.join(format!("{frame:06}"));
        for named in &set.images {
            let mut bytes = Vec::new();
            named
                .image
                .write_to(&mut Cursor::new(&mut bytes), ImageFormat::Png)
                .map_err(|error| {
                    NodeError::item(format!("encoding {} as PNG: {error}", named.name))
                })?;
            self.writes.write(
                folder.join(safe_file_name(&format!(
                    "{}{}.png",
                    named.name, self.params.suffix
                ))),
                bytes,
            )?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        self.writes.flush()
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::sink(
            "png_sink",
            "writes images as 8-bit RGB PNG, one folder per frame",
        )
        .input(IMAGES.spec()),
        |params: &PngSinkParams| {
            if params.out.as_os_str().is_empty() {
                return Err(ParamError::field("out", "is empty").with_accepted("an output folder"));
            }
            Ok(())
        },
        |params: PngSinkParams| {
            Ok(Node::Sink(Box::new(PngSink {
                writes: Writes::new(params.out.clone(), 16),
                params,
                _claim: None,
            })))
        },
    );
}
