//! FID's InceptionV3: the preprocessing against hand-computed values, the network's shapes, and
//! the weights loader against a state dict written under pytorch-fid's names. Real FID weights
//! cannot be fetched here, so the loader is checked on a file of the same layout.

use std::path::Path;

use bevworld_metrics::fid::{FidError, InceptionExtractor, TO_PYTORCH, inception_input};
use bevworld_metrics::inception::{InceptionV3, MIN_INPUT_SIZE, POOL3_FEATURES};
use bevworld_metrics::load_inception;
use burn::prelude::*;
use burn::store::{BurnToPyTorchAdapter, ModuleSnapshot, SafetensorsStore};

fn device() -> Device {
    Device::flex()
}

/// Writes `model` as pytorch-fid's state dict would name it, leaving out tensors whose
/// path `skip` accepts.
fn save_as_pytorch(model: &InceptionV3, path: &Path, skip: Option<fn(&str, &str) -> bool>) {
    let mut store = SafetensorsStore::from_file(path).with_to_adapter(BurnToPyTorchAdapter);
    if let Some(skip) = skip {
        store = store.with_predicate(skip);
    }
    for (from, to) in TO_PYTORCH {
        store = store.with_key_remapping(from, to);
    }
    model.save_into(&mut store).expect("save");
}

/// The network at its smallest input, so that the default test run stays fast on CPU.
fn small(mut extractor: InceptionExtractor) -> InceptionExtractor {
    extractor.input_size = MIN_INPUT_SIZE;
    extractor
}

fn test_image(width: u32, height: u32, seed: u32) -> image::RgbImage {
    image::RgbImage::from_fn(width, height, |x, y| {
        let v = (x * 7 + y * 13 + seed * 31) % 256;
        image::Rgb([v as u8, (255 - v) as u8, ((v * 3) % 256) as u8])
    })
}

#[test]
fn resize_matches_pytorch_half_pixel_bilinear() {
    // Columns 0 and 255 upsampled 2 -> 4 with align_corners=False: the source positions are
    // -0.25 (clamped to 0), 0.25, 0.75 and 1.25 (clamped to the last pixel).
    let image = image::RgbImage::from_fn(2, 2, |x, _| {
        let v = if x == 0 { 0 } else { 255 };
        image::Rgb([v, v, v])
    });
    let out = inception_input(&image, 4);
    let expected = [0.0, 0.25, 0.75, 1.0].map(|v: f32| 2.0 * v - 1.0);
    for c in 0..3 {
        for y in 0..4 {
            for x in 0..4 {
                let got = out[(c * 4 + y) * 4 + x];
                assert!((got - expected[x]).abs() < 1e-6, "c{c} y{y} x{x}: {got}");
            }
        }
    }
    // Same size is the identity, scaled to [-1, 1].
    let image = test_image(5, 5, 1);
    let out = inception_input(&image, 5);
    for y in 0..5 {
        for x in 0..5 {
            for c in 0..3 {
                let v = image.get_pixel(x as u32, y as u32)[c] as f32 / 255.0;
                assert!((out[(c * 5 + y) * 5 + x] - (2.0 * v - 1.0)).abs() < 1e-6);
            }
        }
    }
}

#[test]
fn pool3_features_have_2048_dims_and_are_finite() {
    let model = InceptionV3::init(&device());
    let x = Tensor::<4>::zeros([2, 3, MIN_INPUT_SIZE, MIN_INPUT_SIZE], &device());
    let features = model.forward(x);
    assert_eq!(features.dims(), [2, POOL3_FEATURES]);
    let values = features.into_data().try_to_vec::<f32>().expect("f32");
    assert!(values.iter().all(|v| v.is_finite()));
    // Every branch ends in a ReLU, so the pooled features are non-negative.
    assert!(values.iter().all(|&v| v >= 0.0));
}

#[test]
fn weights_in_pytorch_fid_layout_load_and_reproduce_features() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("inception.safetensors");
    let original = InceptionV3::init(&device());
    save_as_pytorch(&original, &path, None);

    // The file speaks pytorch-fid's names and shapes.
    let bytes = std::fs::read(&path).expect("read");
    let tensors = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    let shape = |name: &str| -> Vec<usize> {
        tensors
            .tensor(name)
            .unwrap_or_else(|e| panic!("{name}: {e}"))
            .shape()
            .to_vec()
    };
    assert_eq!(shape("Conv2d_1a_3x3.conv.weight"), [32, 3, 3, 3]);
    assert_eq!(shape("Conv2d_1a_3x3.bn.weight"), [32]);
    assert_eq!(shape("Mixed_5b.branch_pool.conv.weight"), [32, 192, 1, 1]);
    assert_eq!(shape("Mixed_6b.branch7x7_2.conv.weight"), [128, 128, 1, 7]);
    assert_eq!(shape("Mixed_6e.branch7x7dbl_5.bn.running_var"), [192]);
    assert_eq!(shape("Mixed_7a.branch3x3_2.conv.weight"), [320, 192, 3, 3]);
    assert_eq!(
        shape("Mixed_7c.branch3x3dbl_3b.conv.weight"),
        [384, 384, 3, 1]
    );
    assert_eq!(shape("Mixed_7c.branch_pool.conv.weight"), [192, 2048, 1, 1]);
    let names = tensors.names();
    // InceptionV3 without its auxiliary head has 94 convolutions, each with a batch norm.
    assert_eq!(
        names.iter().filter(|n| n.ends_with(".conv.weight")).count(),
        94
    );
    assert_eq!(names.iter().filter(|n| n.ends_with(".bn.bias")).count(), 94);

    let extractor = small(InceptionExtractor::from_weights(Some(&path), device()).expect("load"));
    let images = [test_image(120, 90, 1), test_image(64, 64, 2)];
    let loaded = extractor.features_of(&images).expect("features");
    let reference = small(InceptionExtractor::new(original, device()))
        .features_of(&images)
        .expect("features");
    assert_eq!(loaded.len(), 2);
    for (a, b) in loaded.iter().zip(&reference) {
        assert_eq!(a.len(), POOL3_FEATURES);
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 * (1.0 + y.abs()), "{x} vs {y}");
        }
    }
}

#[test]
fn fid_of_a_set_with_itself_is_zero_and_of_another_set_is_positive() {
    let extractor = small(InceptionExtractor::new(
        InceptionV3::init(&device()),
        device(),
    ));
    let a: Vec<_> = (0..3).map(|s| test_image(80, 60, s)).collect();
    let b: Vec<_> = (0..3)
        .map(|s| image::RgbImage::from_pixel(80, 60, image::Rgb([(s * 90) as u8, 20, 200])))
        .collect();
    let same = extractor.fid(&a, &a).expect("fid");
    assert!(same.abs() < 1e-3, "FID of a set with itself: {same}");
    let different = extractor.fid(&a, &b).expect("fid");
    assert!(different > same + 1e-3, "{different}");
    // One image gives no covariance: an error, not a number.
    assert!(matches!(
        extractor.fid(&a[..1], &b),
        Err(FidError::Statistics(_))
    ));
}

#[test]
fn missing_or_wrong_weights_are_clear_errors() {
    let none = InceptionExtractor::from_weights(None, device())
        .err()
        .expect("no weights must be an error");
    let message = none.to_string();
    assert!(message.contains("none were given"), "{message}");
    assert!(message.contains("FID was not computed"), "{message}");

    let dir = tempfile::tempdir().expect("tempdir");
    let absent = dir.path().join("absent.pth");
    let err = load_inception(&absent, &device()).expect_err("error");
    assert!(matches!(err, FidError::NotFound { .. }));
    assert!(err.to_string().contains("absent.pth"));

    let odd = dir.path().join("weights.onnx");
    std::fs::write(&odd, b"not weights").expect("write");
    assert!(matches!(
        load_inception(&odd, &device()),
        Err(FidError::UnknownFormat { .. })
    ));

    let garbage = dir.path().join("garbage.safetensors");
    std::fs::write(&garbage, b"\x08\x00\x00\x00\x00\x00\x00\x00not json").expect("write");
    let err = load_inception(&garbage, &device()).expect_err("error");
    assert!(matches!(err, FidError::Load { .. }), "{err}");

    // A state dict without the last block's pool branch: named, not silently random.
    let partial = dir.path().join("partial.safetensors");
    save_as_pytorch(
        &InceptionV3::init(&device()),
        &partial,
        Some(|path: &str, _| !path.contains("mixed_7c.branch_pool")),
    );
    let err = load_inception(&partial, &device()).expect_err("error");
    let message = err.to_string();
    assert!(matches!(err, FidError::Missing { .. }), "{message}");
    assert!(message.contains("mixed_7c.branch_pool"), "{message}");
}
