//! The perceptual loss loads torchvision's VGG16 layout and nothing else: a state dict written
//! under torchvision's names and shapes loads and gives a loss of 0 on identical images and
//! more on different ones; a missing file, a file without a tensor, or no file at all never
//! yields a loss on random weights.

use std::path::Path;

use bevworld_blocks::init::random_tensor;
use bevworld_blocks::seeded_init;
use bevworld_tokenizer_train::perceptual::{PerceptualLoss, TORCHVISION_VGG16, Vgg16Features};
use burn::prelude::*;
use burn::store::{BurnToPyTorchAdapter, ModuleSnapshot, SafetensorsStore};

/// Writes `vgg` under torchvision's `features.{i}` names, leaving out tensors `skip` accepts.
fn save_partial(vgg: &Vgg16Features, path: &Path, skip: fn(&str, &str) -> bool) {
    let mut store = SafetensorsStore::from_file(path)
        .with_to_adapter(BurnToPyTorchAdapter)
        .with_predicate(skip);
    for (k, i) in [0, 2, 5, 7, 10, 12, 14, 17, 19, 21].iter().enumerate() {
        store = store.with_key_remapping(format!(r"^convs\.{k}\."), format!("features.{i}."));
    }
    vgg.save_into(&mut store).expect("save");
}

#[test]
fn a_torchvision_state_dict_loads_and_measures_differences() {
    let device = Device::flex();
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("vgg16.safetensors");
    bevworld_tokenizer_train::perceptual::save_torchvision_layout(
        &seeded_init(1, &device, Vgg16Features::init_unloaded),
        &path,
    )
    .expect("save");
    let loss = PerceptualLoss::from_file(&path, &device).expect("loads");
    let a = random_tensor(2, [1, 3, 32, 48], 0.0, 1.0, &device);
    let b = random_tensor(3, [1, 3, 32, 48], 0.0, 1.0, &device);
    let same: f32 = loss.forward(a.clone(), a.clone()).into_scalar();
    let different: f32 = loss.forward(a, b).into_scalar();
    assert_eq!(same, 0.0);
    assert!(different > 0.0 && different.is_finite(), "{different}");
}

#[test]
fn missing_or_partial_weights_are_refused_by_name() {
    let device = Device::flex();
    let dir = tempfile::tempdir().expect("tempdir");
    let absent = dir.path().join("absent.pth");
    let message = PerceptualLoss::from_file(&absent, &device)
        .expect_err("absent")
        .to_string();
    assert!(
        message.contains("absent.pth") && message.contains(TORCHVISION_VGG16),
        "{message}"
    );

    let partial = dir.path().join("partial.safetensors");
    // Keep everything but the last convolution.
    save_partial(
        &seeded_init(1, &device, Vgg16Features::init_unloaded),
        &partial,
        |path: &str, _: &str| !path.starts_with("convs.9"),
    );
    let message = PerceptualLoss::from_file(&partial, &device)
        .expect_err("partial")
        .to_string();
    assert!(
        message.contains("missing") && message.contains("convs.9"),
        "{message}"
    );
}
