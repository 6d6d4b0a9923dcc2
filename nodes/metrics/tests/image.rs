//! PSNR and SSIM against hand-computed values.

use bevworld_metrics::{Planes, psnr, ssim};

fn planes(data: &[f32], channels: usize, height: usize, width: usize) -> Planes<'_> {
    Planes {
        data,
        channels,
        height,
        width,
    }
}

#[test]
fn psnr_of_identical_images_is_infinite_not_nan() {
    let a = vec![0.25f32; 3 * 16 * 16];
    let value = psnr(&planes(&a, 3, 16, 16), &planes(&a, 3, 16, 16), 1.0).unwrap();
    assert!(value.is_infinite() && value > 0.0);
}

#[test]
fn psnr_hand_computed() {
    // Every value off by 0.1 on a [0, 1] range: MSE = 0.01, PSNR = 10 log10(1 / 0.01) = 20 dB.
    let a = vec![0.5f32; 64];
    let b = vec![0.6f32; 64];
    assert!((psnr(&planes(&a, 1, 8, 8), &planes(&b, 1, 8, 8), 1.0).unwrap() - 20.0).abs() < 1e-5);
    // The same error on an 8-bit range: 25.5 off of 255 is the same 20 dB.
    let a = vec![100.0f32; 64];
    let b = vec![125.5f32; 64];
    assert!((psnr(&planes(&a, 1, 8, 8), &planes(&b, 1, 8, 8), 255.0).unwrap() - 20.0).abs() < 1e-9);
}

#[test]
fn bad_input_is_an_error() {
    let a = vec![0.0f32; 64];
    let b = vec![0.0f32; 48];
    assert!(
        psnr(&planes(&a, 1, 8, 8), &planes(&b, 1, 8, 6), 1.0)
            .unwrap_err()
            .to_string()
            .contains("differ in shape")
    );
    assert!(
        psnr(&planes(&a, 1, 8, 8), &planes(&a, 1, 8, 8), 0.0)
            .unwrap_err()
            .to_string()
            .contains("data range")
    );
    assert!(
        ssim(&planes(&a, 1, 8, 8), &planes(&a, 1, 8, 8), 1.0)
            .unwrap_err()
            .to_string()
            .contains("at least 11x11")
    );
    let nan = vec![f32::NAN; 64];
    assert!(psnr(&planes(&nan, 1, 8, 8), &planes(&a, 1, 8, 8), 1.0).is_err());
}

#[test]
fn ssim_of_identical_images_is_one_and_constants_follow_the_formula() {
    let textured: Vec<f32> = (0..3 * 32 * 32).map(|k| ((k * 37) % 256) as f32).collect();
    let same = ssim(
        &planes(&textured, 3, 32, 32),
        &planes(&textured, 3, 32, 32),
        255.0,
    )
    .unwrap();
    assert!((same - 1.0).abs() < 1e-12);
    // Two constant images a, b: variances vanish, so SSIM = (2ab + C1) / (a^2 + b^2 + C1).
    let (a, b) = (100.0f64, 140.0f64);
    let c1 = (0.01f64 * 255.0).powi(2);
    let expected = (2.0 * a * b + c1) / (a * a + b * b + c1);
    let pa = vec![a as f32; 20 * 20];
    let pb = vec![b as f32; 20 * 20];
    let value = ssim(&planes(&pa, 1, 20, 20), &planes(&pb, 1, 20, 20), 255.0).unwrap();
    assert!((value - expected).abs() < 1e-9, "{value} vs {expected}");
    // Any change lowers SSIM below 1; a perfectly anti-correlated image (255 - x, same means
    // up to a shift) has a negative structure term, so SSIM < 0.
    let noisy: Vec<f32> = textured
        .iter()
        .enumerate()
        .map(|(k, v)| v + if k % 2 == 0 { 20.0 } else { -20.0 })
        .collect();
    assert!(
        ssim(
            &planes(&textured, 3, 32, 32),
            &planes(&noisy, 3, 32, 32),
            255.0
        )
        .unwrap()
            < 1.0 - 1e-3
    );
    let inverted: Vec<f32> = textured.iter().map(|v| 255.0 - v).collect();
    assert!(
        ssim(
            &planes(&textured, 3, 32, 32),
            &planes(&inverted, 3, 32, 32),
            255.0
        )
        .unwrap()
            < 0.0
    );
}
