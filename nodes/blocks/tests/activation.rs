//! Our vectorised GELU against burn's (libm's `erf`), its parts against f64 references, and
//! its hard cases: large magnitudes, zero, infinities and NaN. Training (autodiff) must keep
//! burn's op and its gradient.

use bevworld_blocks::activation::{erf, exp, gelu, gelu_in_place};
use burn::prelude::*;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

/// Points over [-12, 12], denser near 0 where GELU bends.
fn sweep() -> Vec<f32> {
    (-60_000..=60_000)
        .map(|i| {
            let t = i as f32 / 5_000.0;
            t * t.abs()
        })
        .filter(|x| x.abs() <= 12.0)
        .collect()
}

#[test]
fn exp_is_within_a_few_ulp_of_f64() {
    let mut worst = 0.0f64;
    for i in -87_000..=88_000 {
        let x = i as f32 / 1000.0;
        let reference = f64::from(x).exp();
        let relative = ((f64::from(exp(x)) - reference) / reference).abs();
        worst = worst.max(relative);
    }
    assert!(
        worst < 4.0 * f64::from(f32::EPSILON),
        "worst relative error {worst:e}"
    );
    assert_eq!(exp(0.0), 1.0);
    assert_eq!(exp(-1e30), exp(-87.0), "clamped below");
    assert!(exp(f32::NAN).is_nan());
}

#[test]
fn erf_is_within_its_bound_and_odd() {
    let mut worst = 0.0f64;
    for x in sweep() {
        let ours = f64::from(erf(x));
        assert_eq!(erf(-x), -erf(x), "odd at {x}");
        assert!(ours.abs() <= 1.0, "|erf({x})| = {ours} > 1");
        worst = worst.max((ours - erf_f64(f64::from(x))).abs());
    }
    eprintln!("erf: worst absolute error {worst:e}");
    assert!(worst <= 1.2e-7, "worst absolute error {worst:e}");
    assert_eq!(erf(0.0), 0.0);
    assert_eq!(erf(f32::INFINITY), 1.0);
    assert_eq!(erf(f32::NEG_INFINITY), -1.0);
    assert!(erf(f32::NAN).is_nan());
}

/// erf in f64 by its Taylor series for |x| < 3 and the asymptotic continued fraction
/// beyond, each far more accurate than the f32 error being checked.
fn erf_f64(x: f64) -> f64 {
    let a = x.abs();
    let value = if a < 3.0 {
        // erf(x) = 2/√π Σ (-1)^n x^(2n+1) / (n! (2n+1))
        let mut sum = 0.0;
        let mut term = a;
        let mut n = 0.0;
        while term.abs() > 1e-18 || n < 5.0 {
            sum += term / (2.0 * n + 1.0);
            n += 1.0;
            term *= -a * a / n;
        }
        sum * 2.0 / std::f64::consts::PI.sqrt()
    } else {
        // erfc(x) = e^{-x²}/√π · 1/(x + 1/2/(x + 1/(x + 3/2/(x + ...))))
        let mut fraction = a;
        for k in (1..60).rev() {
            fraction = a + f64::from(k) / 2.0 / fraction;
        }
        1.0 - (-a * a).exp() / std::f64::consts::PI.sqrt() / fraction
    };
    value.copysign(x)
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
