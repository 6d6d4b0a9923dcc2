//! Volume rendering weights, `w_i = α_i ∏_{j<i} (1 − α_j)` with `α = σ(s)`, in log space.
//!
//! `log α_i = log σ(s_i)` and `log(1 − α_j) = log σ(−s_j)`, so the exclusive cumulative sum
//! `log T_i = Σ_{j<i} log σ(−s_j)` never multiplies many small numbers: with α near 1 the log
//! transmittance goes to a large negative number and `exp` gives exactly 0, never NaN. The
//! weights sum to `1 − T_N ≤ 1`, the ray's opacity; the rest of the ray is transparent.

use bevworld_blocks::fast_math::{exp, log_sigmoid_pair};
use bevworld_blocks::host::{into_inference_values, vectorized};
use burn::prelude::*;
use burn::tensor::activation;
use rayon::prelude::*;

/// Weights of each sample along each ray, from alpha logits `s`.
///
/// For CPU inference this is one host loop per ray (`render_weights_on_host`); under
/// autodiff or on another device, burn ops with their backward passes.
// [R, S] -> [R, S]
pub fn render_weights(alpha_logits: Tensor<2>) -> Tensor<2> {
    let ([rays, samples], device) = (alpha_logits.dims(), alpha_logits.device());
    let alpha_logits = match into_inference_values(alpha_logits) {
        Ok(mut values) => {
            render_weights_on_host(&mut values, samples);
            return Tensor::from_data(TensorData::new(values, [rays, samples]), &device);
        }
        Err(alpha_logits) => alpha_logits,
    };
    let log_alpha = activation::log_sigmoid(alpha_logits.clone()); // [R, S]
    let log_transparency = activation::log_sigmoid(alpha_logits.neg()); // [R, S], log(1 - α)
    // Exclusive cumulative sum: the inclusive one minus the sample's own term.
    let log_transmittance = log_transparency.clone().cumsum(1) - log_transparency; // [R, S]
    (log_alpha + log_transmittance).exp()
}

/// Rays per parallel task on the host.
const RAYS_PER_TASK: usize = 256;

/// `render_weights` in place over row-major `[R, S]` alpha logits, with the same arithmetic
/// in the same order (inclusive running sum minus the sample's own term), so that it agrees
/// with the tensor ops to a few ulp: per ray, the two log-sigmoids and the final `exp` are
/// vectorised passes, and only the running sum is sequential.
pub fn render_weights_on_host(logits: &mut [f32], samples: usize) {
    if samples == 0 {
        return;
    }
    logits
        .par_chunks_mut(samples * RAYS_PER_TASK)
        .for_each(|rays| vectorized(WeightsKernel { rays, samples }));
}

/// `render_weights_on_host` of one chunk of rays, compiled for the CPU's vector width.
struct WeightsKernel<'a> {
    rays: &'a mut [f32],
    samples: usize,
}

impl macerator::WithSimd for WeightsKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let mut log_transparency = vec![0f32; self.samples];
        for ray in self.rays.chunks_exact_mut(self.samples) {
            for (s, t) in ray.iter_mut().zip(&mut log_transparency) {
                (*s, *t) = log_sigmoid_pair(*s);
            }
            let mut running = 0f32;
            for (s, t) in ray.iter_mut().zip(&log_transparency) {
                running += t;
                *s += running - t;
            }
            for s in ray.iter_mut() {
                *s = exp(*s);
            }
        }
    }
}

/// Log transmittance after each sample (inclusive): `log T_{i+1}`. A ray may stop once it
/// falls below `ln(1e-4)`.
// [R, S] -> [R, S]
pub fn log_transmittance_after(alpha_logits: Tensor<2>) -> Tensor<2> {
    activation::log_sigmoid(alpha_logits.neg()).cumsum(1)
}

/// Expected depth `Σ w_i t_i` of each ray.
// weights [R, S], depths [R, S] or [1, S] -> [R]
pub fn expected_depth(weights: Tensor<2>, depths: Tensor<2>) -> Tensor<1> {
    let [rays, _] = weights.dims();
    (weights * depths).sum_dim(1).reshape([rays])
}

/// Expected feature `Σ w_i v_i` of each ray.
// weights [R, S], features [R, S, C] -> [R, C]
pub fn expected_feature(weights: Tensor<2>, features: Tensor<3>) -> Tensor<2> {
    let [rays, samples] = weights.dims();
    let [_, _, channels] = features.dims();
    weights
        .reshape([rays, 1, samples])
        .matmul(features)
        .reshape([rays, channels])
}
