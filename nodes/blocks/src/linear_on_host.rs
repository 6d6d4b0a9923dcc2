//! burn's `Linear`, `y = x W + b`, for inference on the CPU as our own product, optionally
//! followed by GELU.
//!
//! Why our own: burn's CPU backend makes each product's output with a zero-filled byte vector
//! that it then copies into an allocation of the runtime's alignment (`FlexTensor::empty`), so
//! every linear layer wrote its output three times (zeros, copy, product) and then added the
//! bias in a fourth pass. In the world model those allocations and copies cost as much as the
//! products themselves. Here the output starts as the bias and the product accumulates onto
//! it, gemm splitting it over the cores as burn has it do; the values are gemm's, as burn's.
//! Under autodiff and on other devices, `Linear::forward` runs as before.

use burn::nn::Linear;
use burn::prelude::*;

use crate::activation::gelu_in_place;
use crate::host::{Cores, Right, checked_values, matrix_product, runs_on_host};

/// `layer.forward(x)`.
// x: [..., C_in] -> [..., C_out]
pub fn linear<const D: usize>(layer: &Linear, x: Tensor<D>) -> Tensor<D> {
    forward(layer, x, false)
}

/// `gelu(layer.forward(x))`, the first half of a transformer's MLP.
// x: [..., C_in] -> [..., C_out]
pub fn linear_gelu<const D: usize>(layer: &Linear, x: Tensor<D>) -> Tensor<D> {
    forward(layer, x, true)
}

fn forward<const D: usize>(layer: &Linear, x: Tensor<D>, then_gelu: bool) -> Tensor<D> {
    let weight = layer.weight.val(); // [C_in, C_out]
    if !(runs_on_host(&x) && runs_on_host(&weight)) {
        let y = layer.forward(x);
        return if then_gelu {
            crate::activation::gelu(y)
        } else {
            y
        };
    }
    let [inputs, outputs] = weight.dims();
    let mut dims = x.dims();
    assert_eq!(dims[D - 1], inputs, "the layer takes {inputs} channels");
    dims[D - 1] = outputs;
    let device = x.device();
    let y = product(layer, &checked_values(x), checked_values(weight), then_gelu);
    Tensor::from_data(TensorData::new(y, dims), &device)
}

/// `layer.forward` of row-major `[rows, C_in]` values, as values `[rows, C_out]`, for a kernel
/// that keeps its activations on the host between layers; `None` when the layer is not an
/// f32 CPU inference module (the caller runs the tensor path).
///
/// # Panics
/// When `x` is not a whole number of `C_in` rows.
// x: [R, C_in] -> [R, C_out]
pub fn linear_values(layer: &Linear, x: &[f32]) -> Option<Vec<f32>> {
    let weight = layer.weight.val(); // [C_in, C_out]
    if !runs_on_host(&weight) {
        return None;
    }
    let inputs = weight.dims()[0];
    assert!(
        inputs > 0 && x.len().is_multiple_of(inputs),
        "{} values are not rows of the layer's {inputs} channels",
        x.len()
    );
    Some(product(layer, x, checked_values(weight), false))
}

/// `x W + b` (then GELU), the output started as the bias and the product accumulated onto it.
// x: [R, C_in], weight: [C_in, C_out] -> [R, C_out]
fn product(layer: &Linear, x: &[f32], weight: Vec<f32>, then_gelu: bool) -> Vec<f32> {
    let [inputs, outputs] = layer.weight.dims();
    let rows = x.len() / inputs.max(1);
    // A bias beside a weight on the CPU is on the CPU: the module's parameters share a device.
    let bias = layer.bias.as_ref().map(|b| checked_values(b.val()));
    let mut y = match &bias {
        Some(bias) => bias.repeat(rows),
        None => vec![0f32; rows * outputs],
    };
    if rows > 0 && outputs > 0 {
        matrix_product(
            &mut y,
            x,
            Right::AsIs(&weight),
            [rows, outputs, inputs],
            1.0,
            bias.is_some(),
            Cores::All,
        );
        if then_gelu {
            gelu_in_place(&mut y);
        }
    }
    y
}
