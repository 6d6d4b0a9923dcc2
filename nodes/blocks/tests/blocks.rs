//! The shared blocks against hand computations and the invariants the models rely on:
//! causality, adaLN-Zero's identity start, fixed embeddings, cached constants, seeded
//! initialisation that nothing else in the process can disturb, and checked weights files.

use bevworld_blocks::init::{random_normal, random_tensor};
use bevworld_blocks::swin::{SwinBlockConfig, SwinConfig};
use bevworld_blocks::{
    AdaLnModulationConfig, ModuleFileError, MultiHeadAttentionConfig, TensorCache, causal_mask,
    check_file, gated_residual, layer_norm, load_module, modulate, modulated_layer_norm,
    save_module, seeded_init, sinusoidal_1d, sinusoidal_2d, timestep_embedding,
};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;

use crate::compare::largest_difference;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

/// Every float parameter of a module, flattened in visiting order.
fn parameters<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0.extend(values(param.val()));
        }
    }
    let mut collect = Collect(Vec::new());
    module.visit(&mut collect);
    collect.0
}

#[test]
fn attention_over_one_key_returns_its_value_projected() {
    // With a single token, softmax is 1 whatever the logits: the output is proj(v).
    let attention = seeded_init(1, &device(), |d| {
        MultiHeadAttentionConfig::new(8, 2).init(d)
    });
    let x = random_normal(4, [3, 1, 8], 0.0, 1.0, &device());
    let out = attention.forward(x.clone(), None);
    // The same token twice: both attend to two equal keys, so each sees the same single value.
    let twice = attention.forward(Tensor::cat(vec![x.clone(), x], 1), None);
    let (one, two) = (values(out), values(twice));
    for (row, chunk) in two.chunks(8).enumerate() {
        let expected = &one[(row / 2) * 8..(row / 2 + 1) * 8];
        for (a, b) in chunk.iter().zip(expected) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
    }
}

#[test]
fn a_causal_mask_keeps_later_tokens_out_of_earlier_outputs() {
    let attention = seeded_init(2, &device(), |d| {
        MultiHeadAttentionConfig::new(8, 4).init(d)
    });
    let mask = causal_mask(5, &device()).reshape([1, 1, 5, 5]);
    let x = random_normal(5, [2, 5, 8], 0.0, 1.0, &device());
    let out = values(attention.forward(x.clone(), Some(mask.clone())));
    for k in 0..5 {
        let bump = Tensor::<3>::zeros([2, 5, 8], &device()).slice_assign(
            [0..2, k..k + 1, 0..8],
            Tensor::<3>::ones([2, 1, 8], &device()).mul_scalar(3.0),
        );
        let bumped = values(attention.forward(x.clone() + bump, Some(mask.clone())));
        for batch in 0..2 {
            for token in 0..5 {
                let at =
                    |v: &[f32]| v[(batch * 5 + token) * 8..(batch * 5 + token + 1) * 8].to_vec();
                let change = at(&out)
                    .iter()
                    .zip(at(&bumped))
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                if token < k {
                    assert_eq!(change, 0.0, "token {token} saw token {k}");
                } else {
                    assert!(change > 1e-4, "token {token} must see token {k}");
                }
            }
        }
    }
}

#[test]
fn timestep_embedding_matches_the_formula() {
    let e = values(timestep_embedding(&[0.0, 3.0], 6, &device()));
    // t = 0: cosines 1, sines 0.
    assert_eq!(&e[..6], &[1.0, 1.0, 1.0, 0.0, 0.0, 0.0]);
    // t = 3, half = 3: ω = 1, 10000^(-1/3), 10000^(-2/3).
    let omegas = [
        1.0f64,
        10_000f64.powf(-1.0 / 3.0),
        10_000f64.powf(-2.0 / 3.0),
    ];
    for (i, w) in omegas.iter().enumerate() {
        assert!((f64::from(e[6 + i]) - (3.0 * w).cos()).abs() < 1e-6);
        assert!((f64::from(e[9 + i]) - (3.0 * w).sin()).abs() < 1e-6);
    }
}

#[test]
fn positional_encodings_cover_any_length_and_lay_rows_before_columns() {
    let one = values(sinusoidal_1d(7, 8, &device()));
    assert_eq!(&one[..8], &[0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]);
    // Any count: a longer sequence starts with the shorter one's rows.
    let longer = values(sinusoidal_1d(11, 8, &device()));
    assert_eq!(&longer[..one.len()], &one[..]);
    // 2D: token (y, x) = [1D(y) on half the channels, 1D(x) on the other half].
    let grid = values(sinusoidal_2d(3, 4, 8, &device()));
    let half = values(sinusoidal_1d(4, 4, &device()));
    let token = |y: usize, x: usize| grid[(y * 4 + x) * 8..(y * 4 + x + 1) * 8].to_vec();
    let row = |p: usize| half[p * 4..(p + 1) * 4].to_vec();
    assert_eq!(token(2, 1), [row(2), row(1)].concat());
    assert_eq!(token(0, 3), [row(0), row(3)].concat());
}

#[test]
fn ada_ln_zero_starts_as_the_identity() {
    let modulation = seeded_init(3, &device(), |d| {
        AdaLnModulationConfig::new(16, 8, 3).init(d)
    });
    let condition = random_normal(6, [4, 16], 0.0, 1.0, &device());
    let chunks = modulation.forward(condition);
    assert_eq!(chunks.len(), 3);
    for chunk in &chunks {
        assert_eq!(chunk.dims(), [4, 8]);
        assert!(values(chunk.clone()).iter().all(|v| *v == 0.0));
    }
    let x = random_normal(7, [4, 8], 0.0, 1.0, &device());
    let out = modulate(x.clone(), chunks[0].clone(), chunks[1].clone());
    assert_eq!(values(out), values(x.clone()));
    // And by hand: x·(1 + 0.5) + 2.
    let shifted = modulate(
        x.clone(),
        Tensor::full([4, 8], 2.0, &device()),
        Tensor::full([4, 8], 0.5, &device()),
    );
    for (a, b) in values(shifted).iter().zip(values(x)) {
        assert!((a - (b * 1.5 + 2.0)).abs() < 1e-6);
    }
}

#[test]
fn a_cache_builds_once_per_key_and_device_and_is_shared_by_clones() {
    let cache: TensorCache<usize, 1> = TensorCache::default();
    let mut built = 0;
    let device = device();
    for _ in 0..3 {
        cache.get_or_build(4, &device, || {
            built += 1;
            Tensor::zeros([4], &device)
        });
    }
    assert_eq!(built, 1);
    let clone = cache.clone();
    clone.get_or_build(5, &device, || Tensor::zeros([5], &device));
    // The autodiff device is another entry: a module runs on both.
    let autodiff = device.clone().autodiff();
    cache.get_or_build(4, &autodiff, || Tensor::zeros([4], &autodiff));
    assert_eq!(cache.len(), 3);
}

#[test]
fn swin_blocks_build_their_constants_once() {
    // Under autodiff (training), where the blocks run on tensors; CPU inference builds no
    // mask at all (`host_attention`).
    let device = device().autodiff();
    let block = seeded_init(4, &device, |d| {
        SwinBlockConfig::new(8, 2, 4).with_shifted(true).init(d)
    });
    let x = random_normal(8, [1, 8, 8, 8], 0.0, 1.0, &device);
    let first = values(block.forward(x.clone()));
    let second = values(block.forward(x));
    assert_eq!(first, second);
    let text = format!("{block:?}");
    // One mask and one index (for the one map size and device).
    assert_eq!(text.matches("TensorCache(1 tensors)").count(), 2, "{text}");
}

#[test]
fn the_same_seed_gives_the_same_weights_whatever_runs_beside_it() {
    let config = SwinConfig::new(3, 4, 16, vec![2, 2], vec![2, 4], 4);
    let reference = parameters(&seeded_init(11, &device(), |d| config.init(d)));
    assert_ne!(
        reference,
        parameters(&seeded_init(12, &device(), |d| config.init(d))),
        "another seed gives other weights"
    );
    // Other threads initialise other models and run them (their lazy draws included) while
    // this one is rebuilt again and again.
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|scope| {
        for worker in 0..2u64 {
            let (stop, config) = (&stop, &config);
            scope.spawn(move || {
                let mut seed = 100 + worker;
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let other = seeded_init(seed, &device(), |d| config.init(d));
                    let _ = other.forward(random_tensor(seed, [1, 3, 16, 16], 0.0, 1.0, &device()));
                    seed += 2;
                }
            });
        }
        for _ in 0..6 {
            let again = parameters(&seeded_init(11, &device(), |d| config.init(d)));
            assert_eq!(again, reference);
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
    });
}

#[test]
fn weights_files_round_trip_and_refuse_what_does_not_fit() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("block.bpk");
    let small = SwinConfig::new(3, 4, 16, vec![2], vec![2], 4);
    let module = seeded_init(5, &device(), |d| small.init(d));
    save_module(&module, "test", &path).expect("save");
    let loaded = load_module(small.init(&device()), "test", "small", &path).expect("load");
    assert_eq!(parameters(&loaded), parameters(&module));

    let wider = SwinConfig::new(3, 4, 32, vec![2], vec![2], 4);
    match load_module(wider.init(&device()), "test", "wider", &path) {
        Err(ModuleFileError::Mismatch { config, count, .. }) => {
            assert_eq!(config, "wider");
            assert!(count > 0);
        }
        other => panic!("expected a mismatch, got {other:?}"),
    }
    let missing = dir.path().join("none.bpk");
    match load_module(small.init(&device()), "test", "small", &missing) {
        Err(error @ ModuleFileError::NotFound { .. }) => {
            assert!(error.to_string().contains("none.bpk"), "{error}");
        }
        other => panic!("expected not found, got {other:?}"),
    }
}

#[test]
fn weights_holding_a_nan_are_refused_naming_the_tensor() {
    /// Puts one NaN into the second float tensor visited.
    struct Poison(usize);
    impl ModuleMapper for Poison {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            self.0 += 1;
            if self.0 != 2 {
                return param;
            }
            param.map(|t| {
                let shape = t.shape();
                let mut v = values(t.clone());
                v[0] = f32::NAN;
                Tensor::from_data(TensorData::new(v, shape), &t.device())
            })
        }
    }
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("poisoned.bpk");
    let config = bevworld_blocks::MlpConfig::new(4, 8);
    let module = seeded_init(1, &device(), |d| config.init(d)).map(&mut Poison(0));
    save_module(&module, "test", &path).expect("save");
    match load_module(config.init(&device()), "test", "mlp", &path) {
        Err(error @ ModuleFileError::NonFinite { .. }) => {
            let text = error.to_string();
            // The MLP's tensors in order: fc1.weight, fc1.bias, ...
            assert!(
                text.contains("fc1.bias") && text.contains("1 non-finite"),
                "{text}"
            );
            assert!(text.contains("poisoned.bpk"), "{text}");
        }
        other => panic!("expected a non-finite refusal, got {other:?}"),
    }
}

#[test]
fn a_header_announcing_more_metadata_than_the_file_holds_is_refused_before_reading() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("bitflip.bpk");
    let config = bevworld_blocks::MlpConfig::new(4, 8);
    save_module(&config.init(&device()), "test", &path).expect("save");
    let mut bytes = std::fs::read(&path).expect("read");
    // Bytes 6..10 are the metadata length (after the magic and the version): one high bit
    // flipped asks for 64 MiB more than the file holds.
    bytes[9] ^= 0x04;
    std::fs::write(&path, &bytes).expect("write");
    for error in [
        check_file("test", &path).expect_err("header"),
        load_module(config.init(&device()), "test", "mlp", &path).expect_err("load"),
    ] {
        let text = error.to_string();
        assert!(
            text.contains("bitflip.bpk") && text.contains("announces"),
            "{text}"
        );
    }
}

#[test]
fn the_modulated_norm_agrees_with_its_composition_and_a_hand_computation() {
    // The world model's layout: [B, F, L, C] with one shift and scale per frame, [B, F, 1, C];
    // 40 channels, so the lanes' tail is used too.
    let host = Device::flex();
    let x = random_normal(8, [2, 3, 5, 40], 1.5, 2.0, &host);
    let shift = random_normal(9, [2, 3, 1, 40], 0.0, 1.0, &host);
    let scale = random_normal(10, [2, 3, 1, 40], 0.0, 1.0, &host);
    let fused = values(modulated_layer_norm(
        x.clone(),
        shift.clone(),
        scale.clone(),
        1e-6,
    ));
    let autodiff = host.clone().autodiff();
    let to = |t: Tensor<4>| Tensor::<4>::from_data(t.into_data(), &autodiff);
    let composed = values(modulate(layer_norm(to(x), 1e-6), to(shift), to(scale)));
    let worst = largest_difference(&fused, &composed);
    assert!(worst < 1e-5, "{worst}");
    // By hand: the row (1, 2, 3, 4) has mean 2.5 and biased variance 1.25; with scale 1 and
    // shift 0.5 each value is 2 · (v − 2.5) / √1.25 + 0.5.
    let row = Tensor::<4>::from_data([[[[1.0f32, 2.0, 3.0, 4.0]]]], &host);
    let out = values(modulated_layer_norm(
        row,
        Tensor::full([1, 1, 1, 4], 0.5, &host),
        Tensor::full([1, 1, 1, 4], 1.0, &host),
        0.0,
    ));
    for (v, o) in [1.0f32, 2.0, 3.0, 4.0].iter().zip(out) {
        let expected = 2.0 * (v - 2.5) / 1.25f32.sqrt() + 0.5;
        assert!((o - expected).abs() < 1e-6, "{o} against {expected}");
    }
}

#[test]
fn the_gated_residual_agrees_with_its_composition() {
    let host = Device::flex();
    let x = random_normal(11, [2, 3, 5, 40], 0.0, 1.0, &host);
    let gate = random_normal(12, [2, 3, 1, 40], 0.0, 1.0, &host);
    let h = random_normal(13, [2, 3, 5, 40], 0.0, 1.0, &host);
    let fused = values(gated_residual(x.clone(), gate.clone(), h.clone()));
    let autodiff = host.autodiff();
    let to = |t: Tensor<4>| Tensor::<4>::from_data(t.into_data(), &autodiff);
    let composed = values(gated_residual(
        to(x.clone()),
        to(gate.clone()),
        to(h.clone()),
    ));
    let by_hand = values(x + gate * h);
    for (i, ((a, b), c)) in fused.iter().zip(&composed).zip(&by_hand).enumerate() {
        assert!(
            (a - b).abs() < 1e-6 && (a - c).abs() < 1e-6,
            "{i}: {a} {b} {c}"
        );
    }
}
