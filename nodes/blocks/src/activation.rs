//! GELU, `GELU(x) = x · Φ(x) = ½ · x · (1 + erf(x / √2))`, computed for inference on the CPU
//! as a vectorised loop spread over the cores.
//!
//! Why our own: burn's CPU backend evaluates `erf` one element at a time through libm and on
//! one thread, and in the tokenizer's voxel lift that is ~40% of the time, more than its
//! matmuls. Here `erf` is a pair of minimax polynomials and `exp` a power-of-two scale times a
//! polynomial (Cephes' `expf`), all branch-free f32 arithmetic that the compiler vectorises,
//! over chunks of the tensor in parallel. Both are within a few ulp of libm.
//!
//! Only tensors outside autodiff on the CPU take this path: under autodiff (training) and on
//! other devices, burn's own `gelu`, with its backward pass, runs as before.

use burn::prelude::*;
use rayon::prelude::*;

use crate::host::inference_values;

/// Elements per parallel task.
const ELEMENTS_PER_TASK: usize = 32 * 1024;

/// GELU of every element: ours on CPU inference tensors, burn's everywhere else.
// [...] -> [...]
pub fn gelu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let Some(mut values) = inference_values(&x) else {
        return burn::tensor::activation::gelu(x);
    };
    gelu_in_place(&mut values);
    Tensor::from_data(TensorData::new(values, x.shape()), &x.device())
}

/// `gelu_scalar` of every value, in parallel over chunks.
pub fn gelu_in_place(values: &mut [f32]) {
    values
        .par_chunks_mut(ELEMENTS_PER_TASK)
        .for_each(|chunk| chunk.iter_mut().for_each(|v| *v = gelu_scalar(*v)));
}

/// `½ · x · (1 + erf(x / √2))`.
#[inline(always)]
pub fn gelu_scalar(x: f32) -> f32 {
    0.5 * x * (1.0 + erf(x * std::f32::consts::FRAC_1_SQRT_2))
}

/// `erf` for f32 within a few ulp, branch-free: two minimax polynomials (coefficients as
/// published by Norbert Juffa for `erff`; each within 3e-8 of erf in exact arithmetic, checked
/// in `tests/activation.rs`), both evaluated and one selected, so that the loop vectorises.
/// - `|x| < 0.927734375`: `erf(x) = x + x · P(x²)`;
/// - `0.927734375 ≤ |x| < 4`: `erf(|x|) = 1 − e^{−(a + a · Q(a))}`, `a = |x|`;
/// - `|x| ≥ 4`: `±1` (erf(4) differs from 1 by 1.5e-8, below half an f32 ulp).
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    const P: [f32; 6] = [
        1.283_791_7e-1,
        -3.761_253_4e-1,
        1.128_199_3e-1,
        -2.676_813_5e-2,
        4.991_194_2e-3,
        -5.967_617e-4,
    ];
    const Q: [f32; 7] = [
        1.287_175_1e-1,
        6.348_467e-1,
        1.067_778_8e-1,
        -2.425_462_2e-2,
        3.883_964_4e-3,
        -3.831_971_3e-4,
        1.728_534_7e-5,
    ];
    let a = x.abs();
    let x2 = x * x;
    let near = {
        let p = ((((P[5] * x2 + P[4]) * x2 + P[3]) * x2 + P[2]) * x2 + P[1]) * x2 + P[0];
        x + x * p
    };
    let far = {
        let b = a.min(4.0);
        let q = (((((Q[6] * b + Q[5]) * b + Q[4]) * b + Q[3]) * b + Q[2]) * b + Q[1]) * b + Q[0];
        (1.0 - exp(-(b + b * q))).copysign(x)
    };
    let value = if a < 0.927_734_4 { near } else { far };
    let value = if a >= 4.0 { 1.0f32.copysign(x) } else { value };
    // `min` above drops NaN; give it back.
    if x.is_nan() { x } else { value }
}

/// `e^x` for f32, within ~2 ulp on `[−87, 88]` (clamped outside, NaN stays NaN):
/// `x = n·ln 2 + r` with `|r| ≤ ½ ln 2`, `e^x = 2ⁿ · e^r`, `e^r` by Cephes' polynomial.
/// Rounding uses the 1.5·2²³ trick rather than `round()`, which needs SSE4.1 to vectorise.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    const LOG2_E: f32 = std::f32::consts::LOG2_E;
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    const ROUND: f32 = 12_582_912.0; // 1.5 · 2²³
    let clamped = x.clamp(-87.0, 88.0);
    // `clamp` keeps NaN, and NaN must not reach the integer conversion below as garbage.
    let x = if clamped.is_nan() { 0.0 } else { clamped };
    let n = (x * LOG2_E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e_r = p * r * r + r + 1.0;
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    let value = e_r * scale;
    if clamped.is_nan() { clamped } else { value }
}
