//! Adaptive layer norm (DiT's adaLN-Zero, Peebles and Xie 2023): a condition vector sets the
//! shift, scale and gate of each sub-layer, `x + g · f(LN(x)·(1 + γ) + β)`. The projection
//! starts at zero, so every gated sub-layer starts as the identity.

use burn::nn::{Initializer, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::silu;
use rayon::prelude::*;

use crate::host::{checked_values, runs_on_host, vectorized};

/// Layer normalisation over the last axis without a learned affine (DiT's
/// `elementwise_affine=False`): AdaLN supplies the scale and shift.
// x: [..., C] -> [..., C]
pub fn layer_norm<const D: usize>(x: Tensor<D>, epsilon: f64) -> Tensor<D> {
    let (variance, mean) = x.clone().var_mean_bias(D - 1);
    (x - mean).div(variance.add_scalar(epsilon).sqrt())
}

/// `x · (1 + scale) + shift`, the modulation of a normalised activation.
// x: [..., C], shift and scale broadcastable to it -> [..., C]
pub fn modulate<const D: usize>(x: Tensor<D>, shift: Tensor<D>, scale: Tensor<D>) -> Tensor<D> {
    x.clone() + x * scale + shift
}

/// `modulate(layer_norm(x, ε), shift, scale)`, with one shift and one scale for every token of
/// a group: DiT's `LN(x)·(1 + γ) + β`. On CPU inference it is one pass over each token's
/// channels (`ModulatedNorm`), where burn's ops made eight passes over the whole activation
/// (the mean, the variance, the centring, the division, the modulation's three), a tenth of a
/// world-model pass; under autodiff and on other devices it is the composition above.
// x: [..., L, C], shift and scale: [..., 1, C] -> [..., L, C]
pub fn modulated_layer_norm<const D: usize>(
    x: Tensor<D>,
    shift: Tensor<D>,
    scale: Tensor<D>,
    epsilon: f64,
) -> Tensor<D> {
    let dims = x.dims();
    let on_host = runs_on_host(&x) && runs_on_host(&shift) && runs_on_host(&scale);
    if !(on_host && one_per_group(dims, shift.dims()) && one_per_group(dims, scale.dims())) {
        return modulate(layer_norm(x, epsilon), shift, scale);
    }
    let device = x.device();
    let (channels, tokens) = (dims[D - 1], dims[D - 2]);
    let (shift, scale) = (checked_values(shift), checked_values(scale));
    let mut x = checked_values(x);
    for_each_row_block(&mut x, channels, |first_row, rows| {
        vectorized(ModulatedNorm {
            rows,
            first_row,
            channels,
            tokens,
            shift: &shift,
            scale: &scale,
            epsilon: epsilon as f32,
        })
    });
    Tensor::from_data(TensorData::new(x, dims), &device)
}

/// `x + gate · h`, adaLN-Zero's gated residual, with one gate for every token of a group. On CPU
/// inference it is one pass that adds into `x`'s buffer, where burn's ops made two passes and
/// two new activations; under autodiff and on other devices it is that composition.
// x, h: [..., L, C], gate: [..., 1, C] -> [..., L, C]
pub fn gated_residual<const D: usize>(x: Tensor<D>, gate: Tensor<D>, h: Tensor<D>) -> Tensor<D> {
    let dims = x.dims();
    let on_host = runs_on_host(&x) && runs_on_host(&gate) && runs_on_host(&h);
    if !(on_host && one_per_group(dims, gate.dims()) && h.dims() == dims) {
        return x + gate * h;
    }
    let device = x.device();
    let (channels, tokens) = (dims[D - 1], dims[D - 2]);
    let (gate, h) = (checked_values(gate), checked_values(h));
    let mut x = checked_values(x);
    for_each_row_block(&mut x, channels, |first_row, rows| {
        let at = first_row * channels;
        vectorized(GatedResidual {
            h: &h[at..at + rows.len()],
            rows,
            first_row,
            channels,
            tokens,
            gate: &gate,
        })
    });
    Tensor::from_data(TensorData::new(x, dims), &device)
}

/// Whether `group` (`[..., 1, C]`) holds one vector for every group of tokens of `x`
/// (`[..., L, C]`): a size-1 token axis, every other axis `x`'s.
fn one_per_group<const D: usize>(x: [usize; D], group: [usize; D]) -> bool {
    D >= 2 && group[D - 2] == 1 && (0..D).all(|i| i == D - 2 || group[i] == x[i])
}

/// Runs `kernel` on blocks of whole rows of `channels` values, in parallel, with the index of
/// each block's first row.
fn for_each_row_block(
    values: &mut [f32],
    channels: usize,
    kernel: impl Fn(usize, &mut [f32]) + Send + Sync,
) {
    if channels == 0 {
        return;
    }
    let rows_per_task = (ROWS_ELEMENTS_PER_TASK / channels).max(1);
    values
        .par_chunks_mut(rows_per_task * channels)
        .enumerate()
        .for_each(|(task, rows)| kernel(task * rows_per_task, rows));
}

/// `gated_residual` over rows of `channels` values, starting at row `first_row`.
struct GatedResidual<'a> {
    rows: &'a mut [f32],
    h: &'a [f32],
    first_row: usize,
    channels: usize,
    tokens: usize,
    gate: &'a [f32],
}

impl macerator::WithSimd for GatedResidual<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let c = self.channels;
        for (i, (row, h)) in self
            .rows
            .chunks_exact_mut(c)
            .zip(self.h.chunks_exact(c))
            .enumerate()
        {
            let group = (self.first_row + i) / self.tokens;
            let gate = &self.gate[group * c..(group + 1) * c];
            for ((v, &h), &g) in row.iter_mut().zip(h).zip(gate) {
                *v += g * h;
            }
        }
    }
}

/// Elements of `modulated_layer_norm`'s and `gated_residual`'s rows per parallel task.
const ROWS_ELEMENTS_PER_TASK: usize = 32 * 1024;

/// Partial sums kept apart so that the reductions vectorise.
const LANES: usize = 16;

/// `modulated_layer_norm` over rows of `channels` values, starting at row `first_row`: row `r`
/// belongs to group `r / tokens`, whose shift and scale are that group's `channels` values.
struct ModulatedNorm<'a> {
    rows: &'a mut [f32],
    first_row: usize,
    channels: usize,
    tokens: usize,
    shift: &'a [f32],
    scale: &'a [f32],
    epsilon: f32,
}

impl macerator::WithSimd for ModulatedNorm<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let c = self.channels;
        for (i, row) in self.rows.chunks_exact_mut(c).enumerate() {
            let group = (self.first_row + i) / self.tokens;
            let shift = &self.shift[group * c..(group + 1) * c];
            let scale = &self.scale[group * c..(group + 1) * c];
            let mean = lane_sum(row, |v| v) / c as f32;
            let variance = lane_sum(row, |v| (v - mean) * (v - mean)) / c as f32;
            let inverse = 1.0 / (variance + self.epsilon).sqrt();
            for ((v, &b), &g) in row.iter_mut().zip(shift).zip(scale) {
                let n = (*v - mean) * inverse;
                *v = n + n * g + b;
            }
        }
    }
}

/// `Σ f(v)` over `LANES` independent partial sums.
#[inline(always)]
fn lane_sum(values: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut sums = [0f32; LANES];
    let blocks = values.chunks_exact(LANES);
    let tail: f32 = blocks.remainder().iter().map(|&v| f(v)).sum();
    for block in blocks {
        for (s, &v) in sums.iter_mut().zip(block) {
            *s += f(v);
        }
    }
    sums.iter().sum::<f32>() + tail
}

#[derive(Config, Debug)]
pub struct AdaLnModulationConfig {
    /// Width of the condition vector.
    pub condition: usize,
    /// Width of the modulated activations.
    pub dim: usize,
    /// Vectors produced, e.g. 3 per sub-layer (shift, scale, gate).
    pub chunks: usize,
}

/// `Linear(SiLU(c))`, split into `chunks` vectors of width `dim`; zero at initialisation.
#[derive(Module, Debug)]
pub struct AdaLnModulation {
    linear: Linear,
    #[module(skip)]
    chunks: usize,
}

impl AdaLnModulationConfig {
    pub fn init(&self, device: &Device) -> AdaLnModulation {
        AdaLnModulation {
            linear: LinearConfig::new(self.condition, self.chunks * self.dim)
                .with_initializer(Initializer::Zeros)
                .init(device),
            chunks: self.chunks,
        }
    }
}

impl AdaLnModulation {
    // c: [..., condition] -> chunks × [..., dim]
    pub fn forward<const D: usize>(&self, condition: Tensor<D>) -> Vec<Tensor<D>> {
        self.linear
            .forward(silu(condition))
            .chunk(self.chunks, D - 1)
    }
}
