//! FID: the Fréchet distance between InceptionV3 pool3 features of two image sets.
//!
//! The weights cannot be fetched here, so they come from a file the user supplies: pytorch-fid's
//! `pt_inception-2015-12-05-6726825d.pth`, or the same state dict saved as `.safetensors`.
//! Nothing ever runs on random Inception weights: without a file there is no FID, and the
//! caller says so.
//!
//! Preprocessing follows pytorch-fid: RGB in [0, 1], bilinear resize to 299 x 299 with
//! half-pixel centres (PyTorch's `align_corners=False`, no antialiasing), then `2x - 1`.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use thiserror::Error;

use crate::frechet::{FeatureExtractor, FrechetError, frechet_distance_of_features};
use crate::inception::{INCEPTION_SIZE, InceptionV3, MIN_INPUT_SIZE, POOL3_FEATURES};
use bevworld_blocks::{TorchLoadError, load_torch_state_dict};

/// The file FID's reference implementation uses, for messages.
pub const PYTORCH_FID_WEIGHTS: &str = "pt_inception-2015-12-05-6726825d.pth";

#[derive(Debug, Error)]
pub enum FidError {
    #[error(
        "FID needs InceptionV3 weights, and none were given: pass the path of pytorch-fid's \
         {PYTORCH_FID_WEIGHTS} (or a .safetensors copy of it). FID was not computed."
    )]
    NoWeights,
    #[error("InceptionV3 weights {path}: file not found")]
    NotFound { path: PathBuf },
    #[error(
        "InceptionV3 weights {path}: unknown extension (accepted: .pth, .pt, .bin for PyTorch; \
         .safetensors)"
    )]
    UnknownFormat { path: PathBuf },
    #[error("InceptionV3 weights {path}: {message}")]
    Load { path: PathBuf, message: String },
    #[error(
        "InceptionV3 weights {path}: {count} tensors missing, e.g. {examples}; is this \
         pytorch-fid's FID Inception?"
    )]
    Missing {
        path: PathBuf,
        count: usize,
        examples: String,
    },
    #[error("FID: {0}")]
    Statistics(#[from] FrechetError),
    #[error("FID: an image has no pixels")]
    EmptyImage,
    #[error("FID: reading InceptionV3 features back: {0}")]
    Readback(String),
}

/// Renames the PyTorch state dict's top-level modules to our fields (`Mixed_5b` -> `mixed_5b`).
const FROM_PYTORCH: [(&str, &str); 2] = [("^Conv2d_", "conv2d_"), ("^Mixed_", "mixed_")];
/// The reverse, for writing a state dict under PyTorch's names.
pub const TO_PYTORCH: [(&str, &str); 2] = [("^conv2d_", "Conv2d_"), ("^mixed_", "Mixed_")];

/// Loads InceptionV3 weights, checking that every tensor of the network was in the file.
pub fn load_inception(path: &Path, device: &Device) -> Result<InceptionV3, FidError> {
    let path_buf = path.to_path_buf();
    load_torch_state_dict(InceptionV3::init(device), path, &FROM_PYTORCH).map_err(|e| match e {
        TorchLoadError::NotFound => FidError::NotFound { path: path_buf },
        TorchLoadError::UnknownFormat => FidError::UnknownFormat { path: path_buf },
        TorchLoadError::Load(message) => FidError::Load {
            path: path_buf,
            message,
        },
        TorchLoadError::Missing { count, examples } => FidError::Missing {
            path: path_buf,
            count,
            examples,
        },
    })
}

/// Resizes an RGB image to `size x size` bilinearly with half-pixel centres and scales it to
/// [-1, 1], channel-major: the network's input for one image.
pub fn inception_input(image: &image::RgbImage, size: usize) -> Vec<f32> {
    let (width, height) = (image.width() as usize, image.height() as usize);
    // One axis's source index pair and weight for each output index, as PyTorch computes them.
    let taps = |input: usize| -> Vec<(usize, usize, f32)> {
        let scale = input as f32 / size as f32;
        (0..size)
            .map(|o| {
                let source = ((o as f32 + 0.5) * scale - 0.5).max(0.0);
                let low = (source as usize).min(input - 1);
                let high = (low + 1).min(input - 1);
                (low, high, source - low as f32)
            })
            .collect()
    };
    let (rows, columns) = (taps(height), taps(width));
    let raw = image.as_raw();
    let mut out = vec![0.0f32; 3 * size * size];
    for (y, &(y0, y1, wy)) in rows.iter().enumerate() {
        for (x, &(x0, x1, wx)) in columns.iter().enumerate() {
            for c in 0..3 {
                let at = |yy: usize, xx: usize| raw[(yy * width + xx) * 3 + c] as f32 / 255.0;
                let top = at(y0, x0) * (1.0 - wx) + at(y0, x1) * wx;
                let bottom = at(y1, x0) * (1.0 - wx) + at(y1, x1) * wx;
                let value = top * (1.0 - wy) + bottom * wy;
                out[(c * size + y) * size + x] = 2.0 * value - 1.0;
            }
        }
    }
    out
}

/// InceptionV3 pool3 features, from loaded weights.
pub struct InceptionExtractor {
    model: InceptionV3,
    device: Device,
    /// Images per forward pass.
    pub batch: usize,
    /// Side the images are resized to: 299 for FID. Smaller sides (at least 75) run the same
    /// network faster, for tests; their features are not comparable with FID's.
    pub input_size: usize,
}

impl InceptionExtractor {
    pub fn new(model: InceptionV3, device: Device) -> Self {
        Self {
            model,
            device,
            batch: 8,
            input_size: INCEPTION_SIZE,
        }
    }

    /// Loads the weights from `path`, or says that FID cannot be computed without them.
    pub fn from_weights(path: Option<&Path>, device: Device) -> Result<Self, FidError> {
        let path = path.ok_or(FidError::NoWeights)?;
        Ok(Self::new(load_inception(path, &device)?, device))
    }

    /// Pool3 features of many images, `batch` at a time.
    pub fn features_of(&self, images: &[image::RgbImage]) -> Result<Vec<Vec<f64>>, FidError> {
        let mut rows = Vec::with_capacity(images.len());
        let side = self.input_size.max(MIN_INPUT_SIZE);
        for chunk in images.chunks(self.batch.max(1)) {
            let mut input = Vec::with_capacity(chunk.len() * 3 * side * side);
            for image in chunk {
                if image.width() == 0 || image.height() == 0 {
                    return Err(FidError::EmptyImage);
                }
                input.extend(inception_input(image, side));
            }
            let x = Tensor::<4>::from_data(
                TensorData::new(input, [chunk.len(), 3, side, side]),
                &self.device,
            );
            let features = self.model.forward(x); // [b, 2048]
            let values = features
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| FidError::Readback(format!("{e:?}")))?;
            rows.extend(
                values
                    .chunks(POOL3_FEATURES)
                    .map(|row| row.iter().map(|&v| v as f64).collect()),
            );
        }
        Ok(rows)
    }

    /// FID between two image sets (each needs at least two images).
    pub fn fid(
        &self,
        generated: &[image::RgbImage],
        reference: &[image::RgbImage],
    ) -> Result<f64, FidError> {
        Ok(frechet_distance_of_features(
            &self.features_of(generated)?,
            &self.features_of(reference)?,
        )?)
    }
}

impl FeatureExtractor for InceptionExtractor {
    fn name(&self) -> &str {
        "inception_v3_pool3"
    }

    fn dimension(&self) -> usize {
        POOL3_FEATURES
    }

    type Error = FidError;

    fn features(&self, image: &image::RgbImage) -> Result<Vec<f64>, FidError> {
        self.features_of(std::slice::from_ref(image))?
            .pop()
            .ok_or(FidError::EmptyImage)
    }
}
