//! The reconstruction losses of one step (the paper's `L_rgb` L1 term and `L_lidar`), computed
//! on the rays drawn for that step only.

use burn::prelude::*;

/// Mean absolute difference.
// [..] x [..] -> [1]
pub fn l1<const D: usize>(prediction: Tensor<D>, target: Tensor<D>) -> Tensor<1> {
    (prediction - target).abs().mean()
}

/// Mean squared difference.
// [..] x [..] -> [1]
pub fn mse<const D: usize>(prediction: Tensor<D>, target: Tensor<D>) -> Tensor<1> {
    (prediction - target).powi_scalar(2).mean()
}
