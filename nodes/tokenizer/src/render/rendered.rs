//! What rendering gives back on the host, whichever renderer made it: the dense tensor path
//! (`batched.rs`), the fused CPU march (`march.rs`) or empty-space skipping (`skipping.rs`).

use burn::prelude::*;

/// What rendering a set of rays gives, on the host.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderedRays {
    /// Expected voxel feature per ray, `[R, C_v]` row-major.
    pub features: Vec<f32>,
    pub channels: usize,
    /// Expected depth `Σ w_i t_i` per ray, metres.
    pub depth: Vec<f32>,
    /// `1 − T` per ray: how much of the ray the scene absorbed.
    pub opacity: Vec<f32>,
    /// Samples that went through trilinear sampling and the alpha head (the cost), against the
    /// `rays × samples` a dense render evaluates.
    pub samples_evaluated: u64,
    pub samples_dense: u64,
}

impl RenderedRays {
    /// `rays` rays of `channels` features, all zero, with nothing evaluated yet of the
    /// `rays × samples` a dense render evaluates.
    pub fn zeros(rays: usize, channels: usize, samples: usize) -> Self {
        Self {
            features: vec![0.0; rays * channels],
            channels,
            depth: vec![0.0; rays],
            opacity: vec![0.0; rays],
            samples_evaluated: 0,
            samples_dense: (rays * samples) as u64,
        }
    }

    pub fn rays(&self) -> usize {
        self.depth.len()
    }

    /// The opacities as a tensor `[R]`.
    pub fn opacity_tensor(&self, device: &Device) -> Tensor<1> {
        Tensor::from_data(TensorData::new(self.opacity.clone(), [self.rays()]), device)
    }

    /// The features of rays `start .. start + count` as a tensor `[count, C_v]`.
    pub fn features_tensor(&self, start: usize, count: usize, device: &Device) -> Tensor<2> {
        let c = self.channels;
        Tensor::from_data(
            TensorData::new(
                self.features[start * c..(start + count) * c].to_vec(),
                [count, c],
            ),
            device,
        )
    }
}

/// A tensor's values on the host, row-major.
pub(crate) fn host_vec<const D: usize>(tensor: Tensor<D>) -> Vec<f32> {
    tensor.into_data().try_to_vec::<f32>().unwrap_or_default()
}
