//! GELU, `GELU(x) = x · Φ(x) = ½ · x · (1 + erf(x / √2))`, and softmax over the last axis,
//! computed for inference on the CPU as vectorised loops spread over the cores.
//!
//! Why our own: burn's CPU backend evaluates `erf` one element at a time through libm and on
//! one thread, and in the tokenizer's voxel lift that is ~40% of the time, more than its
//! matmuls. Here `erf` is `fast_math::erf`, branch-free f32 arithmetic that the compiler
//! vectorises, over chunks of the tensor in parallel. Softmax is the same story: burn's rows
//! call libm's `expf` once per element, a quarter of the lift's time; ours uses
//! `fast_math::exp`.
//!
//! Only tensors outside autodiff on the CPU take this path: under autodiff (training) and on
//! other devices, burn's own `gelu` and `softmax`, with their backward passes, run as before.

use burn::prelude::*;
use rayon::prelude::*;

use crate::fast_math::{erf, exp};
use crate::host::{into_inference_values, map_in_place, vectorized};

/// Elements per parallel task.
const ELEMENTS_PER_TASK: usize = 32 * 1024;

/// GELU of every element: ours on CPU inference tensors, burn's everywhere else.
// [...] -> [...]
pub fn gelu<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let (shape, device) = (x.shape(), x.device());
    match into_inference_values(x) {
        Ok(mut values) => {
            gelu_in_place(&mut values);
            Tensor::from_data(TensorData::new(values, shape), &device)
        }
        Err(x) => burn::tensor::activation::gelu(x),
    }
}

/// `gelu_scalar` of every value, in parallel over chunks.
pub fn gelu_in_place(values: &mut [f32]) {
    values
        .par_chunks_mut(ELEMENTS_PER_TASK)
        .for_each(|chunk| map_in_place(chunk, gelu_scalar));
}

/// `½ · x · (1 + erf(x / √2))`.
#[inline(always)]
pub fn gelu_scalar(x: f32) -> f32 {
    0.5 * x * (1.0 + erf(x * std::f32::consts::FRAC_1_SQRT_2))
}

/// Softmax over the last axis: ours on CPU inference tensors, burn's everywhere else.
// [..., N] -> [..., N]
pub fn softmax_last<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let (shape, device) = (x.shape(), x.device());
    match into_inference_values(x) {
        Ok(mut values) => {
            softmax_rows_in_place(&mut values, shape.dims::<D>()[D - 1]);
            Tensor::from_data(TensorData::new(values, shape), &device)
        }
        Err(x) => burn::tensor::activation::softmax(x, D - 1),
    }
}

/// Softmax of every row of `row` values, in place: `e^{x − max} / Σ e^{x − max}`, rows in
/// parallel over chunks, each chunk one vectorised kernel.
pub fn softmax_rows_in_place(values: &mut [f32], row: usize) {
    if row == 0 {
        return;
    }
    let rows_per_task = (ELEMENTS_PER_TASK / row).max(1);
    values
        .par_chunks_mut(row * rows_per_task)
        .for_each(|rows| vectorized(SoftmaxRows { rows, row }));
}

/// Lanes of the partial maxima and sums: independent accumulators, so that the reductions
/// vectorise (one running sum would have to add in order).
const LANES: usize = 16;

struct SoftmaxRows<'a> {
    rows: &'a mut [f32],
    row: usize,
}

impl macerator::WithSimd for SoftmaxRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        for values in self.rows.chunks_exact_mut(self.row) {
            softmax_row(values);
        }
    }
}

/// Softmax of one row in place, written to vectorise: the maximum and the sum over
/// `LANES` independent accumulators, the exponentials in a loop of their own.
#[inline(always)]
pub fn softmax_row(values: &mut [f32]) {
    let mut lanes = [f32::NEG_INFINITY; LANES];
    let mut blocks = values.chunks_exact(LANES);
    for block in &mut blocks {
        for (m, &v) in lanes.iter_mut().zip(block) {
            *m = m.max(v);
        }
    }
    let max = blocks
        .remainder()
        .iter()
        .chain(&lanes)
        .fold(f32::NEG_INFINITY, |m, &v| m.max(v));
    for v in values.iter_mut() {
        *v = exp(*v - max);
    }
    let mut sums = [0f32; LANES];
    let mut blocks = values.chunks_exact(LANES);
    for block in &mut blocks {
        for (s, &v) in sums.iter_mut().zip(block) {
            *s += v;
        }
    }
    let sum: f32 = blocks.remainder().iter().chain(&sums).sum();
    let inverse = 1.0 / sum;
    for v in values.iter_mut() {
        *v *= inverse;
    }
}
