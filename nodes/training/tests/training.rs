//! The training machinery against hand computations: the schedule, the generator's draws,
//! the weights' moving average, the metrics log read by column name, the curves, and the
//! data-parallel map, whose failures are the same with one thread as with many.

use bevworld_blocks::seeded_init;
use bevworld_training::ema::{effective_decay, update};
use bevworld_training::metrics_log::{MetricsLog, Row, read_series};
use bevworld_training::schedule::learning_rate;
use bevworld_training::{Curve, WorkerPanicked, parallel_map, plot_curves};
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;

/// Every float a module holds, in module order.
fn module_values<M: Module>(module: &M) -> Vec<f32> {
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let data = param.val().into_data().try_to_vec::<f32>().expect("f32");
            self.0.extend(data);
        }
    }
    let mut collect = Collect(Vec::new());
    module.visit(&mut collect);
    collect.0
}

#[test]
fn the_schedule_warms_up_then_follows_the_cosine() {
    // Warm-up: lr · (step + 1) / warmup.
    assert!((learning_rate(1e-3, 10, 110, 0.1, 0) - 1e-4).abs() < 1e-12);
    assert!((learning_rate(1e-3, 10, 110, 0.1, 9) - 1e-3).abs() < 1e-12);
    // Start of the decay, its middle (half way between lr and the floor), and the end.
    assert!((learning_rate(1e-3, 10, 110, 0.1, 10) - 1e-3).abs() < 1e-12);
    assert!((learning_rate(1e-3, 10, 110, 0.1, 60) - 0.55e-3).abs() < 1e-12);
    assert!((learning_rate(1e-3, 10, 110, 0.1, 110) - 1e-4).abs() < 1e-12);
}

#[test]
fn the_weight_average_follows_the_warmed_up_decay() {
    use burn::module::ModuleMapper;
    use burn::nn::LinearConfig;

    // d = min(decay, (1 + t) / (10 + t)): 2/11 after step 1, 0.9 from step 80 on.
    assert!((effective_decay(0.9, 1) - 2.0 / 11.0).abs() < 1e-12);
    assert!((effective_decay(0.9, 80) - 81.0 / 90.0).abs() < 1e-12);
    assert_eq!(effective_decay(0.9, 1000), 0.9);

    struct Fill(f32);
    impl ModuleMapper for Fill {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            let (id, tensor, mapper) = param.consume();
            Param::from_mapped_value(id, tensor.zeros_like().add_scalar(self.0), mapper)
        }
    }
    let device = Device::flex();
    let linear = seeded_init(1, &device, |d| LinearConfig::new(3, 2).init(d));
    let average = linear.clone().map(&mut Fill(1.0));
    let model = linear.map(&mut Fill(3.0));
    // Step 1: 2/11 · 1 + 9/11 · 3 = 29/11; step 1000: 0.9 · 1 + 0.1 · 3 = 1.2.
    for (step, expected) in [(1, 29.0 / 11.0), (1000, 1.2)] {
        let moved = update(average.clone(), &model, 0.9, step).expect("same module");
        let values = module_values(&moved);
        assert_eq!(values.len(), 3 * 2 + 2);
        for v in values {
            assert!((f64::from(v) - expected).abs() < 1e-6, "step {step}: {v}");
        }
    }
    // Another module's parameters are refused, not blended.
    let other = seeded_init(2, &device, |d| LinearConfig::new(2, 2).init(d));
    let error = update(average, &other, 0.9, 1).expect_err("different shapes");
    assert!(error.to_string().contains("differ in"), "{error}");
}

#[test]
fn the_metrics_log_is_read_by_column_name_and_refuses_unknown_columns() {
    let dir = tempfile::tempdir().expect("dir");
    // The columns in an unusual order: readers must not care.
    let columns = ["phase", "psnr_db", "step", "loss", "elapsed_s"];
    let mut log = MetricsLog::open(dir.path(), &columns, None).expect("open");
    for (step, loss) in [(1, 0.5), (2, 0.25)] {
        log.append(&Row {
            step,
            phase: "train",
            elapsed_s: 1.25,
            values: vec![("loss", loss)],
        })
        .expect("append");
    }
    log.append(&Row {
        step: 2,
        phase: "val",
        elapsed_s: 3.0,
        values: vec![("psnr_db", 21.5)],
    })
    .expect("append");
    let text = std::fs::read_to_string(log.path()).expect("read");
    assert_eq!(
        text,
        "phase,psnr_db,step,loss,elapsed_s\ntrain,,1,0.500000,1.2\ntrain,,2,0.250000,1.2\nval,21.500000,2,,3.0\n"
    );
    assert_eq!(
        read_series(log.path(), "train", "loss").expect("loss"),
        [(1.0, 0.5), (2.0, 0.25)]
    );
    assert_eq!(
        read_series(log.path(), "val", "psnr_db").expect("psnr"),
        [(2.0, 21.5)]
    );
    let error = log
        .append(&Row {
            step: 3,
            phase: "train",
            elapsed_s: 4.0,
            values: vec![("loss_typo", 1.0)],
        })
        .expect_err("an unknown column");
    assert!(error.to_string().contains("loss_typo"), "{error}");
    let missing = read_series(log.path(), "val", "chamfer_m2").expect_err("no such column");
    assert!(missing.to_string().contains("chamfer_m2"), "{missing}");

    // Resuming at step 1 drops the rows a crashed run wrote after its checkpoint, and the
    // resumed session's times continue from the kept rows' last (1.2 s, as written).
    let mut log = MetricsLog::open(dir.path(), &columns, Some(1)).expect("reopen");
    let text = std::fs::read_to_string(log.path()).expect("read");
    assert_eq!(text.lines().count(), 2, "{text}");
    log.append(&Row {
        step: 2,
        phase: "train",
        elapsed_s: 0.5,
        values: vec![("loss", 0.125)],
    })
    .expect("append");
    let text = std::fs::read_to_string(log.path()).expect("read");
    assert!(text.ends_with("train,,2,0.125000,1.7\n"), "{text}");
    // A fresh run starts at 0 whatever the folder held.
    let mut log = MetricsLog::open(dir.path(), &columns, None).expect("fresh");
    log.append(&Row {
        step: 1,
        phase: "train",
        elapsed_s: 0.5,
        values: vec![],
    })
    .expect("append");
    let text = std::fs::read_to_string(log.path()).expect("read");
    assert!(text.ends_with("train,,1,,0.5\n"), "{text}");
}

#[test]
fn curves_are_drawn_from_the_named_columns() {
    let dir = tempfile::tempdir().expect("dir");
    let columns = ["step", "phase", "loss", "psnr_db", "elapsed_s"];
    let mut log = MetricsLog::open(dir.path(), &columns, None).expect("open");
    for step in 1..=20 {
        log.append(&Row {
            step,
            phase: "train",
            elapsed_s: 0.0,
            values: vec![("loss", 1.0 / step as f64)],
        })
        .expect("append");
    }
    let png = dir.path().join("curves.png");
    let curves = [
        Curve {
            title: "loss",
            phase: "train",
            column: "loss",
            log_scale: true,
        },
        Curve {
            title: "PSNR",
            phase: "val",
            column: "psnr_db",
            log_scale: false,
        },
    ];
    plot_curves(log.path(), &png, &curves).expect("curves");
    let image = image::open(&png).expect("png").to_rgb8();
    assert_eq!(image.width(), 2 * 420);
    let absent = [Curve {
        title: "Chamfer",
        phase: "val",
        column: "chamfer_m2",
        log_scale: true,
    }];
    let error = plot_curves(log.path(), &png, &absent).expect_err("no such column");
    assert!(error.to_string().contains("chamfer_m2"), "{error}");
}

#[test]
fn a_panicking_item_fails_the_map_with_one_thread_as_with_many() {
    let items: Vec<usize> = (0..6).collect();
    for threads in [1, 2, 4] {
        let result = parallel_map(
            &items,
            threads,
            || (),
            |_, &i| {
                assert!(i != 3, "item three is broken");
                i * 10
            },
        );
        match result {
            Err(WorkerPanicked { item, message }) => {
                assert_eq!(item, 3, "{threads} threads");
                assert!(message.contains("item three is broken"), "{message}");
            }
            Ok(values) => panic!("{threads} threads: a panic passed as {values:?}"),
        }
        let fine = parallel_map(&items, threads, || (), |_, &i| i * 10).expect("no panic");
        assert_eq!(
            fine,
            [0, 10, 20, 30, 40, 50],
            "{threads} threads keep item order"
        );
    }
}

#[test]
fn a_checkpoint_is_refused_when_its_step_or_files_were_changed() {
    use bevworld_training::checkpoint::{self, CheckpointError, CheckpointState};
    let dir = tempfile::tempdir().expect("dir");
    let run = dir.path();
    let staged = checkpoint::staging(run, 5).expect("staging");
    std::fs::write(staged.file("model.bpk"), b"weights of step five").expect("write");
    std::fs::write(staged.file("optimizer.bpk"), b"moments").expect("write");
    let state = CheckpointState {
        step: 5,
        rng_state: 42,
    };
    let folder = checkpoint::commit(run, staged, &state, 3).expect("commit");
    let (_, read) = checkpoint::latest(run).expect("a checkpoint as written resumes");
    assert_eq!(read, state);

    let refusal = |what: &str| -> String {
        match checkpoint::latest(run) {
            Err(error @ CheckpointError::Io { .. }) => error.to_string(),
            other => panic!("{what}: expected a refusal, got {other:?}"),
        }
    };
    let state_path = folder.join("state.json");
    let original = std::fs::read_to_string(&state_path).expect("state");
    for edited in [999, 25] {
        let text = original.replace("\"step\": 5", &format!("\"step\": {edited}"));
        assert_ne!(text, original);
        std::fs::write(&state_path, text).expect("edit");
        let message = refusal("an edited step");
        assert!(message.contains("state.json"), "{message}");
        assert!(message.contains(&format!("step {edited}")), "{message}");
        assert!(message.contains("step-0000005"), "{message}");
    }
    std::fs::write(&state_path, &original).expect("restore");

    let model = folder.join("model.bpk");
    let mut bytes = std::fs::read(&model).expect("model");
    bytes[3] ^= 0x40;
    std::fs::write(&model, &bytes).expect("flip");
    let message = refusal("a flipped byte");
    assert!(message.contains("model.bpk"), "{message}");
    assert!(message.contains("digest"), "{message}");
    bytes[3] ^= 0x40;
    std::fs::write(&model, &bytes).expect("unflip");
    assert!(checkpoint::latest(run).is_ok());

    std::fs::remove_file(folder.join("optimizer.bpk")).expect("remove");
    let message = refusal("a missing file");
    assert!(message.contains("optimizer.bpk"), "{message}");
    std::fs::write(folder.join("optimizer.bpk"), b"moments").expect("restore");

    std::fs::write(folder.join("stray.bpk"), b"from another run").expect("stray");
    let message = refusal("a file it did not write");
    assert!(message.contains("stray.bpk"), "{message}");
    std::fs::remove_file(folder.join("stray.bpk")).expect("remove");

    // A state.json of the format before digests: refused, saying why.
    std::fs::write(&state_path, r#"{"step": 5, "rng_state": 42}"#).expect("legacy");
    let message = refusal("a checkpoint without digests");
    assert!(message.contains("before checkpoints recorded"), "{message}");
    std::fs::write(&state_path, &original).expect("restore");

    // The pointer must name a checkpoint folder, not a path out of the run.
    std::fs::write(
        checkpoint::checkpoints_dir(run).join("latest"),
        "../../elsewhere",
    )
    .expect("pointer");
    let message = refusal("a pointer out of the folder");
    assert!(message.contains("latest"), "{message}");
}

#[test]
fn two_parts_are_clipped_by_their_joint_norm_as_one_model_would_be() {
    use bevworld_training::{Part, apply_gradients, apply_gradients_in_two};
    use burn::nn::{Linear, LinearConfig};
    use burn::optim::GradientsParams;

    #[derive(Module, Debug)]
    struct Pair {
        a: Linear,
        b: Linear,
    }
    let device = Device::flex().autodiff();
    let pair = seeded_init(3, &device, |d| Pair {
        a: LinearConfig::new(3, 2).init(d),
        b: LinearConfig::new(2, 1).init(d),
    });
    let x = Tensor::<2>::from_floats([[1.0, -2.0, 0.5], [0.3, 0.7, -1.1]], &device);
    let loss = pair.b.forward(pair.a.forward(x)).powf_scalar(2.0).sum();
    let mut grads = loss.backward();
    let grads_a = GradientsParams::from_module(&mut grads, &pair.a);
    let grads_b = GradientsParams::from_module(&mut grads, &pair.b);
    // The joint norm by hand: every parameter's squared gradient, summed over both parts.
    let mut squares = 0.0f64;
    for values in [
        module_grads(&pair.a, &grads_a),
        module_grads(&pair.b, &grads_b),
    ] {
        squares += values.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>();
    }
    let expected_norm = squares.sqrt();
    assert!(expected_norm > 0.1, "the gradient is not trivial");
    let max_norm = expected_norm / 4.0;

    let config = bevworld_training::OptimizerConfig {
        lr: 0.1,
        beta_1: 0.9,
        beta_2: 0.999,
        epsilon: 1e-8,
        weight_decay: 0.0,
        warmup_steps: 0,
        final_lr_fraction: 1.0,
        decay_steps: None,
        grad_clip_norm: max_norm,
    };
    // The same gradients for the pair as one model.
    let mut whole = GradientsParams::new();
    for (part, grads) in [(&pair.a, &grads_a), (&pair.b, &grads_b)] {
        copy_grads(part, grads, &mut whole);
    }
    let (mut first, mut second) = (config.adamw(), config.adamw());
    let (a, b, norm) = apply_gradients_in_two(
        Part {
            model: pair.a.clone(),
            optimizer: &mut first,
            grads: vec![grads_a],
            lr: 0.1,
        },
        Part {
            model: pair.b.clone(),
            optimizer: &mut second,
            grads: vec![grads_b],
            lr: 0.1,
        },
        max_norm,
    )
    .expect("a finite norm");
    assert!((norm - expected_norm).abs() < 1e-5 * expected_norm);

    let (joined, joined_norm) =
        apply_gradients(pair.clone(), &mut config.adamw(), [whole], max_norm, 0.1)
            .expect("a finite norm");
    assert!((joined_norm - norm).abs() < 1e-9);
    let split: Vec<f32> = [module_values(&a), module_values(&b)].concat();
    for (x, y) in split.iter().zip(module_values(&joined)) {
        assert!((x - y).abs() < 1e-6, "{x} against {y}");
    }
    // And the step moved the weights.
    assert_ne!(
        split,
        [module_values(&pair.a), module_values(&pair.b)].concat()
    );
}

fn module_grads<M: Module>(module: &M, grads: &burn::optim::GradientsParams) -> Vec<f32> {
    struct Collect<'a>(&'a burn::optim::GradientsParams, Vec<f32>);
    impl ModuleVisitor for Collect<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(grad) = self.0.get::<D>(param.id) {
                self.1
                    .extend(grad.into_data().try_to_vec::<f32>().expect("f32"));
            }
        }
    }
    let mut collect = Collect(grads, Vec::new());
    module.visit(&mut collect);
    collect.1
}

fn copy_grads<M: Module>(
    module: &M,
    from: &burn::optim::GradientsParams,
    into: &mut burn::optim::GradientsParams,
) {
    struct Copy<'a>(
        &'a burn::optim::GradientsParams,
        &'a mut burn::optim::GradientsParams,
    );
    impl ModuleVisitor for Copy<'_> {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            if let Some(grad) = self.0.get::<D>(param.id) {
                self.1.register(param.id, grad);
            }
        }
    }
    module.visit(&mut Copy(from, into));
}
