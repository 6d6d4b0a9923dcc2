//! The perceptual term of `L_rgb`: `Σ_j mean |φ_j(I_g) − φ_j(I_t)|` over VGG16 features at
//! relu1_2, relu2_2, relu3_3 and relu4_3, on images normalised with ImageNet statistics.
//!
//! The weights are torchvision's `vgg16` state dict (`vgg16-397923af.pth`, or the same as
//! `.safetensors`), supplied by the user: they cannot be fetched here, and the term never runs
//! on random VGG weights. Without a file the term is off and the trainer says so.

use std::path::{Path, PathBuf};

use bevworld_blocks::{TorchLoadError, load_torch_state_dict};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::prelude::*;
use burn::store::{BurnToPyTorchAdapter, ModuleSnapshot, SafetensorsStore};
use burn::tensor::activation::relu;

/// torchvision's file, for messages.
pub const TORCHVISION_VGG16: &str = "vgg16-397923af.pth";

/// Channels of VGG16's first ten convolutions (through conv4_3), and after which of them the
/// feature is taken (relu1_2, relu2_2, relu3_3, relu4_3) or a 2x2 max-pool follows.
const CHANNELS: [(usize, usize); 10] = [
    (3, 64),
    (64, 64),
    (64, 128),
    (128, 128),
    (128, 256),
    (256, 256),
    (256, 256),
    (256, 512),
    (512, 512),
    (512, 512),
];
const TAPS: [usize; 4] = [1, 3, 6, 9];
/// The index of each of those convolutions in torchvision's `features` Sequential.
const TORCH_INDEX: [usize; 10] = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21];
const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

#[derive(Debug, thiserror::Error)]
pub enum PerceptualError {
    #[error(
        "VGG16 weights {path}: {source}; give torchvision's {TORCHVISION_VGG16} (or a .safetensors copy)"
    )]
    Load {
        path: PathBuf,
        source: TorchLoadError,
    },
}

#[derive(Module, Debug)]
pub struct Vgg16Features {
    convs: Vec<Conv2d>,
    pool: MaxPool2d,
}

impl Vgg16Features {
    /// The network with random weights: only for `load_vgg16` to fill, and for tests that
    /// write a state dict. The loss refuses to be built on it.
    pub fn init_unloaded(device: &Device) -> Self {
        Self {
            convs: CHANNELS
                .iter()
                .map(|&(i, o)| {
                    Conv2dConfig::new([i, o], [3, 3])
                        .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                        .init(device)
                })
                .collect(),
            pool: MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
        }
    }

    /// The four tapped feature maps.
    // [N, 3, H, W] in [0, 1] -> 4 x [N, C_j, H_j, W_j]
    pub fn forward(&self, images: Tensor<4>) -> Vec<Tensor<4>> {
        let device = images.device();
        let stat = |v: [f32; 3]| {
            Tensor::<1>::from_data(TensorData::new(v.to_vec(), [3]), &device).reshape([1, 3, 1, 1])
        };
        let mut x = (images - stat(IMAGENET_MEAN)) / stat(IMAGENET_STD);
        let mut taps = Vec::with_capacity(TAPS.len());
        for (i, conv) in self.convs.iter().enumerate() {
            x = relu(conv.forward(x));
            if TAPS.contains(&i) {
                taps.push(x.clone());
                if i + 1 < self.convs.len() {
                    x = self.pool.forward(x);
                }
            }
        }
        taps
    }
}

/// The key renames from torchvision (`features.5.weight`) to our fields (`convs.2.weight`).
pub fn torchvision_remaps() -> Vec<(String, String)> {
    TORCH_INDEX
        .iter()
        .enumerate()
        .map(|(k, i)| (format!(r"^features\.{i}\."), format!("convs.{k}.")))
        .collect()
}

/// Writes `vgg` as a torchvision state dict (`features.{i}.weight`, `.bias`) in safetensors:
/// the layout `load_vgg16` reads, for converting weights and for tests.
pub fn save_torchvision_layout(vgg: &Vgg16Features, path: &Path) -> Result<(), PerceptualError> {
    let mut store = SafetensorsStore::from_file(path).with_to_adapter(BurnToPyTorchAdapter);
    for (k, i) in TORCH_INDEX.iter().enumerate() {
        store = store.with_key_remapping(format!(r"^convs\.{k}\."), format!("features.{i}."));
    }
    vgg.save_into(&mut store)
        .map_err(|e| PerceptualError::Load {
            path: path.to_path_buf(),
            source: TorchLoadError::Load(e.to_string()),
        })
}

/// Loads VGG16's convolutions through conv4_3; every one of their tensors must be in the file.
pub fn load_vgg16(path: &Path, device: &Device) -> Result<Vgg16Features, PerceptualError> {
    let remaps = torchvision_remaps();
    let pairs: Vec<(&str, &str)> = remaps
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    load_torch_state_dict(Vgg16Features::init_unloaded(device), path, &pairs).map_err(|source| {
        PerceptualError::Load {
            path: path.to_path_buf(),
            source,
        }
    })
}

/// The perceptual loss, built only from loaded weights.
#[derive(Module, Debug)]
pub struct PerceptualLoss {
    vgg: Vgg16Features,
}

impl PerceptualLoss {
    pub fn from_file(path: &Path, device: &Device) -> Result<Self, PerceptualError> {
        Ok(Self {
            vgg: load_vgg16(path, device)?,
        })
    }

    /// `Σ_j mean |φ_j(a) − φ_j(b)|`.
    // [N, 3, H, W] x [N, 3, H, W] -> [1]
    pub fn forward(&self, rendered: Tensor<4>, target: Tensor<4>) -> Tensor<1> {
        let (a, b) = (self.vgg.forward(rendered), self.vgg.forward(target));
        a.into_iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs().mean())
            .reduce(|s, t| s + t)
            .unwrap_or_else(|| Tensor::zeros([1], &Device::default()))
    }
}
