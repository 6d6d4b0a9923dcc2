//! Volume rendering weights, `w_i = α_i ∏_{j<i} (1 − α_j)` with `α = σ(s)`, in log space.
//!
//! `log α_i = log σ(s_i)` and `log(1 − α_j) = log σ(−s_j)`, so the exclusive cumulative sum
//! `log T_i = Σ_{j<i} log σ(−s_j)` never multiplies many small numbers: with α near 1 the log
//! transmittance goes to a large negative number and `exp` gives exactly 0, never NaN. The
//! weights sum to `1 − T_N ≤ 1`, the ray's opacity; the rest of the ray is transparent.

use burn::prelude::*;
use burn::tensor::activation::log_sigmoid;

/// Weights of each sample along each ray, from alpha logits `s`.
// [R, S] -> [R, S]
pub fn render_weights(alpha_logits: Tensor<2>) -> Tensor<2> {
    let log_alpha = log_sigmoid(alpha_logits.clone()); // [R, S]
    let log_transparency = log_sigmoid(alpha_logits.neg()); // [R, S], log(1 - α)
    // Exclusive cumulative sum: the inclusive one minus the sample's own term.
    let log_transmittance = log_transparency.clone().cumsum(1) - log_transparency; // [R, S]
    (log_alpha + log_transmittance).exp()
}

/// Log transmittance after each sample (inclusive): `log T_{i+1}`. A ray may stop once it
/// falls below `ln(1e-4)`.
// [R, S] -> [R, S]
pub fn log_transmittance_after(alpha_logits: Tensor<2>) -> Tensor<2> {
    log_sigmoid(alpha_logits.neg()).cumsum(1)
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
