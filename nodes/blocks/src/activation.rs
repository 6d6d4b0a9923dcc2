//! GELU, `GELU(x) = x · Φ(x) = ½ · x · (1 + erf(x / √2))`, computed for inference on the CPU
//! as a vectorised loop spread over the cores.
//!
//! Why our own: burn's CPU backend evaluates `erf` one element at a time through libm and on
//! one thread, and in the tokenizer's voxel lift that is ~40% of the time, more than its
//! matmuls. Here `erf` is `fast_math::erf`, branch-free f32 arithmetic that the compiler
//! vectorises, over chunks of the tensor in parallel.
//!
//! Only tensors outside autodiff on the CPU take this path: under autodiff (training) and on
//! other devices, burn's own `gelu`, with its backward pass, runs as before.

use burn::prelude::*;
use rayon::prelude::*;

use crate::fast_math::erf;
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
