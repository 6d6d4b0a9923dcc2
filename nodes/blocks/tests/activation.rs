//! Our vectorised GELU against burn's (libm's `erf`) and its hard cases: large magnitudes,
//! zero, infinities and NaN. Training (autodiff) must keep burn's op and its gradient.

use crate::reference;
use reference::{erf_f64, sweep};

use bevworld_blocks::activation::{gelu, gelu_in_place};
use burn::prelude::*;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

#[test]
fn gelu_matches_burns_on_cpu_inference_tensors() {
    let device = Device::flex();
    let xs = sweep();
    let n = xs.len();
    let input = Tensor::<1>::from_data(TensorData::new(xs.clone(), [n]), &device);
    let ours = values(gelu(input.clone()));
    let burns = values(burn::tensor::activation::gelu(input));
    for ((x, a), b) in xs.iter().zip(&ours).zip(&burns) {
        let tolerance = 1e-7 * x.abs().max(1.0) + 2.0 * f32::EPSILON * b.abs();
        assert!(
            (a - b).abs() <= tolerance,
            "GELU({x}): ours {a}, burn's {b}"
        );
    }
}

#[test]
fn gelu_keeps_shape_and_hard_cases() {
    let device = Device::flex();
    let input = Tensor::<3>::from_data(
        TensorData::new(
            vec![
                0.0,
                -0.0,
                1e-30,
                -1e-30,
                30.0,
                -30.0,
                f32::INFINITY,
                f32::NAN,
            ],
            [2, 2, 2],
        ),
        &device,
    );
    let output = gelu(input);
    assert_eq!(output.dims(), [2, 2, 2]);
    let v = values(output);
    assert_eq!(v[0], 0.0);
    assert_eq!(v[1], 0.0);
    assert!((v[2] - 0.5e-30).abs() < 1e-36, "tiny positive: {}", v[2]);
    assert_eq!(v[4], 30.0, "far right is the identity");
    assert_eq!(v[5], 0.0, "far left is zero");
    assert_eq!(v[6], f32::INFINITY);
    assert!(v[7].is_nan(), "NaN stays NaN");
    let mut empty: Vec<f32> = Vec::new();
    gelu_in_place(&mut empty);
}

#[test]
fn under_autodiff_gelu_is_burns_with_its_gradient() {
    let device = Device::flex().autodiff();
    let xs = vec![-2.0f32, -0.5, 0.0, 0.7, 3.0];
    let x = Tensor::<1>::from_data(TensorData::new(xs.clone(), [5]), &device).require_grad();
    let y = gelu(x.clone());
    let reference = burn::tensor::activation::gelu(x.clone().detach());
    assert_eq!(
        values(y.clone()),
        values(reference),
        "autodiff runs burn's op exactly"
    );
    let gradients = y.sum().backward();
    let grad = values(x.grad(&gradients).expect("gradient of x"));
    for (x, g) in xs.iter().zip(grad) {
        // d/dx GELU = Φ(x) + x φ(x)
        let x = f64::from(*x);
        let pdf = (-x * x / 2.0).exp() / (2.0 * std::f64::consts::PI).sqrt();
        let expected = 0.5 * (1.0 + erf_f64(x / std::f64::consts::SQRT_2)) + x * pdf;
        assert!(
            (f64::from(g) - expected).abs() < 1e-5,
            "GELU'({x}) = {g}, expected {expected}"
        );
    }
}
