//! Our vectorisable f32 math against f64 references, over its whole useful range and at its
//! hard cases: the ends of the range, zero, infinities and NaN.

use bevworld_blocks::fast_math::{erf, exp, log_sigmoid, log1p};

use crate::reference;
use reference::{erf_f64, sweep};

#[test]
fn exp_is_within_a_few_ulp_of_f64() {
    let mut worst = 0.0f64;
    for i in -86_999..=87_999 {
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

#[test]
fn exp_flushes_below_the_normal_range_and_overflows_above_it() {
    assert_eq!(exp(-87.5), 0.0);
    assert_eq!(exp(-1e30), 0.0);
    assert_eq!(exp(f32::NEG_INFINITY), 0.0);
    assert_eq!(exp(88.5), f32::INFINITY);
    assert_eq!(exp(f32::INFINITY), f32::INFINITY);
}

#[test]
fn log1p_is_within_a_few_ulp_from_tiny_to_large() {
    let mut worst = 0.0f64;
    let mut y = 1e-30f32;
    while y < 1e6 {
        let reference = f64::from(y).ln_1p();
        worst = worst.max(((f64::from(log1p(y)) - reference) / reference).abs());
        y *= 1.0007;
    }
    eprintln!("log1p: worst relative error {worst:e}");
    assert!(
        worst < 4.0 * f64::from(f32::EPSILON),
        "worst relative error {worst:e}"
    );
    assert_eq!(log1p(0.0), 0.0);
    assert_eq!(log1p(f32::INFINITY), f32::INFINITY);
    assert!(log1p(f32::NAN).is_nan());
}

#[test]
fn log_sigmoid_is_stable_and_accurate_over_the_logits_a_renderer_sees() {
    let mut worst = 0.0f64;
    for i in -200_000..=200_000 {
        let x = i as f32 / 1000.0;
        let x64 = f64::from(x);
        let reference = x64.min(0.0) - (-x64.abs()).exp().ln_1p();
        let error = (f64::from(log_sigmoid(x)) - reference).abs() / reference.abs().max(1e-30);
        worst = worst.max(error);
    }
    eprintln!("log_sigmoid: worst relative error {worst:e}");
    assert!(
        worst < 8.0 * f64::from(f32::EPSILON),
        "worst relative error {worst:e}"
    );
    // The padding logit of the skipping renderer: α = 0 and log(1 − α) = 0 exactly.
    assert_eq!(log_sigmoid(1e4), 0.0);
    assert_eq!(log_sigmoid(-1e4), -1e4);
    assert_eq!(log_sigmoid(f32::NEG_INFINITY), f32::NEG_INFINITY);
    assert!(log_sigmoid(f32::NAN).is_nan());
}

/// The host kernels dispatch to the widest instructions the CPU reports, so that a build or a
/// library update that falls back to scalar code on a vector CPU is noticed here, not in a
/// benchmark.
#[test]
fn host_kernels_dispatch_to_the_widest_instructions_the_cpu_has() {
    let level = bevworld_blocks::host::dispatch_level();
    #[cfg(target_arch = "x86_64")]
    {
        // x86-64-v4: the AVX-512 subsets every AVX-512 server CPU has.
        let v4 = std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512cd")
            && std::is_x86_feature_detected!("avx512dq")
            && std::is_x86_feature_detected!("avx512vl");
        let v3 = std::is_x86_feature_detected!("avx2") && std::is_x86_feature_detected!("fma");
        let expected: &[&str] = if v4 {
            &["avx512", "avx512-fp16"]
        } else if v3 {
            &["avx2+fma"]
        } else if std::is_x86_feature_detected!("sse4.2") {
            &["sse4.2"]
        } else {
            &["scalar"]
        };
        assert!(
            expected.contains(&level),
            "the CPU offers {expected:?}, the host kernels dispatch to {level}"
        );
    }
    #[cfg(not(target_arch = "x86_64"))]
    assert_ne!(level, "other", "an unnamed dispatch level");
}
