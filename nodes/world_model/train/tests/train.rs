//! Training the world model on small hand-made latent caches: what the cache loader refuses,
//! gaps split rather than stitched, baselines that are exact where the world stands still,
//! one step that lowers the loss, a sequence overfit, and runs that resume and split their
//! work bit for bit.

use std::path::{Path, PathBuf};

use bevworld_sinks::npy::npy_f32;
use bevworld_types::{LatentStats, Manoeuvre, Pose};
use bevworld_world_model::{ActionStats, EgoWarpBase, LatentGrid, WorldModelConfig};
use bevworld_world_model_train::config::{KEYFRAMES_INDEX, SWEEPS_INDEX};
use bevworld_world_model_train::{
    DataError, Expected, HorizonScores, Rate, TrainWorldModelConfig, TrainingData, WindowShape,
    WindowValues, WorldModelTrainer, load_sequences,
};
use burn::prelude::*;
use glam::{DQuat, DVec3};

const C: usize = 4;
const H: usize = 16;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../..")
}

/// The tiny model made small enough for many steps in a test.
fn small_model() -> WorldModelConfig {
    let mut c =
        WorldModelConfig::from_yaml_file(&repo().join("configs/models/world-model-tiny.yaml"))
            .expect("model config");
    c.latent_size = [H, H];
    c.width = 32;
    c.heads = 2;
    c.depth = 1;
    c.condition_half = 16;
    c.context_frames = 2;
    c.future_frames = 2;
    c.x_range = [-8.0, 8.0];
    c.y_range = [-8.0, 8.0];
    c
}

fn grid() -> LatentGrid {
    LatentGrid {
        channels: C,
        height: H,
        width: H,
        x_range: [-8.0, 8.0],
        y_range: [-8.0, 8.0],
    }
}

/// A world of fixed features seen from an ego at `x` metres along the global x axis: cell
/// (i, j) at ego point (x_j, y_i) holds a smooth function of the global point.
fn latent_at(ego_x: f64) -> Vec<f32> {
    let mut values = Vec::with_capacity(C * H * H);
    for c in 0..C {
        for i in 0..H {
            for j in 0..H {
                let (x, y) = (ego_x + (j as f64 - 7.5), i as f64 - 7.5);
                values.push(((x * 0.4 + c as f64).sin() + (y * 0.3).cos()) as f32);
            }
        }
    }
    values
}

fn pose(x: f64) -> Pose {
    Pose::from_rotation_translation(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0))
}

fn rows(p: &Pose) -> Vec<[f64; 4]> {
    let m = glam::DMat4::from(*p);
    (0..4)
        .map(|r| [m.col(0)[r], m.col(1)[r], m.col(2)[r], m.col(3)[r]])
        .collect()
}

/// One frame of a hand-made cache: scene, time, ego x, and its latent.
struct Frame {
    scene: &'static str,
    time_us: i64,
    x: f64,
    latent: Vec<f32>,
}

fn write_cache(dir: &Path, index: &str, frames: &[Frame], hash: &str) {
    std::fs::create_dir_all(dir).expect("dir");
    let mut entries = Vec::new();
    for (n, f) in frames.iter().enumerate() {
        let file = format!("{}-{n}.npy", f.scene);
        let shape = [C, H, H];
        std::fs::write(dir.join(&file), npy_f32(&shape, &f.latent).expect("npy")).expect("write");
        entries.push(serde_json::json!({
            "frame_token": format!("{}-{n}", f.scene),
            "sample_token": "s",
            "scene": f.scene,
            "timestamp_us": f.time_us,
            "global_from_ego": rows(&pose(f.x)),
            "file": file,
            "shape": shape,
            "model": "tokenizer-test",
            "weights_hash": hash,
        }));
    }
    let index_json = serde_json::json!({"format": "npy", "frames": entries});
    std::fs::write(
        dir.join(index),
        serde_json::to_vec(&index_json).expect("json"),
    )
    .expect("index");
}

/// A scene driving along x at `speed` m/s, `count` frames `interval_us` apart.
fn drive(scene: &'static str, count: usize, interval_us: i64, speed: f64) -> Vec<Frame> {
    (0..count)
        .map(|k| {
            let x = speed * k as f64 * interval_us as f64 * 1e-6;
            Frame {
                scene,
                time_us: 1_000_000 + k as i64 * interval_us,
                x,
                latent: latent_at(x),
            }
        })
        .collect()
}

fn expected() -> Expected {
    Expected {
        model: "tokenizer-test".into(),
        weights_hash: "abc".into(),
        shape: [C, H, H],
        stats: LatentStats {
            mean: vec![0.0; C],
            std: vec![1.0; C],
            frames: 1,
        },
        gap_factor: 1.5,
    }
}

#[test]
fn a_scene_with_a_time_gap_is_split_never_stitched() {
    let dir = tempfile::tempdir().expect("dir");
    let mut frames = drive("a", 6, 500_000, 2.0);
    // Frames 3.. arrive 2 s late: a gap of 2.5 s against the usual 0.5 s.
    for f in frames.iter_mut().skip(3) {
        f.time_us += 2_000_000;
    }
    frames.extend(drive("b", 4, 500_000, 2.0));
    write_cache(dir.path(), "index.json", &frames, "abc");
    let sequences = load_sequences(dir.path(), "index.json", &expected()).expect("load");
    assert_eq!(sequences.gaps, 1);
    let lengths: Vec<usize> = sequences.sequences.iter().map(|s| s.frames.len()).collect();
    assert_eq!(lengths, vec![3, 3, 4]);
    // No window of 3 frames (with the frame before it) crosses the gap: only scene b has one.
    assert_eq!(sequences.windows(3), vec![(2, 1)]);
}

#[test]
fn a_strided_stage_draws_every_sixth_sweep_from_any_start() {
    let dir = tempfile::tempdir().expect("dir");
    write_cache(
        dir.path(),
        "index.json",
        &drive("a", 13, 83_333, 6.0),
        "abc",
    );
    let sweeps = load_sequences(dir.path(), "index.json", &expected()).expect("load");
    let strided = sweeps.strided(6);
    // Offsets 0 to 5: frames {0, 6, 12}, {1, 7}, ..., {5, 11}.
    let tokens: Vec<Vec<String>> = strided
        .sequences
        .iter()
        .map(|s| s.frames.iter().map(|f| f.token.clone()).collect())
        .collect();
    assert_eq!(tokens[0], vec!["a-0", "a-6", "a-12"]);
    assert_eq!(tokens[5], vec!["a-5", "a-11"]);
    assert_eq!(tokens.len(), 6);
    assert_eq!(strided.frames(), 13, "every frame once");
    for sequence in &strided.sequences {
        for pair in sequence.frames.windows(2) {
            assert_eq!(pair[1].time_us - pair[0].time_us, 6 * 83_333);
        }
    }
    // The action into a strided frame spans 0.5 s at 6 m/s: 3 m.
    let action = strided.sequences[1].action_into(1).expect("action");
    assert!((action.speed_mps - 6.0).abs() < 1e-6, "{action:?}");
    // Two-frame windows with the frame before them: only offset 0 has three frames.
    assert_eq!(strided.windows(2), vec![(0, 1)]);
    assert_eq!(sweeps.strided(1).frames(), 13);

    let mut config = train_config(dir.path());
    config.stages[2].stride = 0;
    let problems = config.problems();
    assert!(
        problems.iter().any(|p| p.field == "stages[2].stride"),
        "{problems:?}"
    );
    // Weights of another tokenizer to adapt, but no weights named.
    let mut config = train_config(dir.path());
    config.init_from_other_tokenizer = true;
    let problems = config.problems();
    assert!(
        problems
            .iter()
            .any(|p| p.field == "init_from_other_tokenizer"),
        "{problems:?}"
    );
    config.init = Some(dir.path().join("trained.bpk"));
    assert!(config.problems().is_empty(), "{:?}", config.problems());
}

#[test]
fn a_stage_with_branches_draws_from_the_training_and_the_branched_scenes() {
    let dir = tempfile::tempdir().expect("dir");
    let (mut data, actions) = training_data(dir.path());
    // Two branches of one context, 6 keyframes each.
    let mut branched = drive("b-left", 6, 500_000, 2.0);
    branched.extend(drive("b-right", 6, 500_000, 3.0));
    let branch_dir = dir.path().join("branches");
    write_cache(&branch_dir, SWEEPS_INDEX, &branched, "abc");
    write_cache(&branch_dir, KEYFRAMES_INDEX, &branched, "abc");
    let e = expected();
    let branch_keyframes = load_sequences(&branch_dir, KEYFRAMES_INDEX, &e).expect("load");
    assert_eq!(branch_keyframes.sequences.len(), 2);
    let joined = data.keyframes.joined(&branch_keyframes);
    assert_eq!(
        joined.frames(),
        data.keyframes.frames() + 12,
        "every frame of both, once"
    );
    assert_eq!(joined.sequences[1].scene, "b-left");

    let mut config = train_config(dir.path());
    config.stages[2].with_branches = true;
    // Named by a stage, but no cache to read it from.
    let problems = config.problems();
    assert!(
        problems
            .iter()
            .any(|p| p.field == "stages[2].with_branches"),
        "{problems:?}"
    );
    let mut branches = config.val.clone();
    branches.latents = branch_dir.clone();
    config.branches = Some(branches);
    // The validation scenes are never learnt from.
    let problems = config.problems();
    assert!(
        problems
            .iter()
            .any(|p| p.field == "val.synth.seed" && p.to_string().contains("branches seeds")),
        "{problems:?}"
    );
    let mut branches = config.train.clone();
    branches.latents = branch_dir.clone();
    config.branches = Some(branches);
    assert!(config.problems().is_empty(), "{:?}", config.problems());
    // Exported and loaded only while a stage reads it.
    assert!(config.branches_in_use().is_some());
    let mut unread = config.clone();
    unread.stages[2].with_branches = false;
    assert!(unread.branches_in_use().is_none());
    // Nor are the test scenes.
    let mut leaky = config.clone();
    if let Some(test) = leaky.test.as_mut() {
        test.synth.seed = config.train.synth.seed + 1;
    }
    let problems = leaky.problems();
    assert!(
        problems
            .iter()
            .any(|p| p.field == "test.synth.seed" && p.to_string().contains("training seeds")),
        "{problems:?}"
    );

    // Not loaded: refused, naming the stage.
    let error = WorldModelTrainer::new(
        config.clone(),
        small_model(),
        actions.clone(),
        training_data(dir.path()).0,
        &Device::flex().autodiff(),
        1,
    )
    .err()
    .expect("no branched latents");
    assert!(
        error.to_string().contains("stage 'long-sequence'"),
        "{error}"
    );
    data.branches = Some((
        load_sequences(&branch_dir, SWEEPS_INDEX, &e).expect("sweeps"),
        branch_keyframes,
    ));
    let mut trainer = WorldModelTrainer::new(
        config,
        small_model(),
        actions,
        data,
        &Device::flex().autodiff(),
        1,
    )
    .expect("trainer");
    // Stage 3 (keyframes, 2 + 2 frames and the frame before them): 8 - 4 = 4 windows of the
    // training keyframes, and 6 - 4 = 2 of each branch.
    let plain = trainer_of(dir.path(), 1, small_model()).windows_per_stage();
    let with = trainer.windows_per_stage();
    assert_eq!(plain[2], 4);
    assert_eq!(
        with[..2],
        plain[..2],
        "stages without branches are unchanged"
    );
    assert_eq!(with[2], 4 + 2 * 2);
    trainer.train_step().expect("a step");
}

#[test]
fn bad_caches_are_refused_naming_the_file() {
    let dir = tempfile::tempdir().expect("dir");
    let mut frames = drive("a", 4, 500_000, 2.0);
    frames[2].latent[17] = f32::NAN;
    write_cache(dir.path(), "index.json", &frames, "abc");
    match load_sequences(dir.path(), "index.json", &expected()) {
        Err(error @ DataError::NonFinite { .. }) => {
            assert!(error.to_string().contains("a-2.npy"), "{error}");
        }
        other => panic!("expected a NaN refusal, got {other:?}"),
    }

    let mut other = expected();
    other.shape = [C, 32, 32];
    write_cache(
        dir.path(),
        "index.json",
        &drive("a", 4, 500_000, 2.0),
        "abc",
    );
    let error = load_sequences(dir.path(), "index.json", &other).expect_err("shape");
    let text = error.to_string();
    assert!(
        text.contains("[4, 16, 16]") && text.contains("[4, 32, 32]"),
        "{text}"
    );

    write_cache(
        dir.path(),
        "index.json",
        &drive("a", 4, 500_000, 2.0),
        "fff",
    );
    let error = load_sequences(dir.path(), "index.json", &expected()).expect_err("weights");
    assert!(
        error.to_string().contains("fff") && error.to_string().contains("abc"),
        "{error}"
    );

    let error = load_sequences(dir.path(), "missing.json", &expected()).expect_err("missing");
    assert!(error.to_string().contains("missing.json"), "{error}");
}

#[test]
fn ego_warp_is_exact_where_the_world_stands_still_and_copy_last_is_not() {
    let dir = tempfile::tempdir().expect("dir");
    // 1 m a frame: one cell, so the warp moves whole cells and is exact inside the grid.
    write_cache(
        dir.path(),
        "index.json",
        &drive("a", 8, 500_000, 2.0),
        "abc",
    );
    let sequences = load_sequences(dir.path(), "index.json", &expected()).expect("load");
    let actions = ActionStats::compute(sequences.actions().iter()).expect("stats");
    let shape = WindowShape {
        context: 2,
        future: 3,
        grid: grid(),
        base: EgoWarpBase {
            residual: true,
            fade_s: None,
        },
        fine: None,
    };
    let window = WindowValues::cut(&sequences.sequences[0], 1, &shape, &actions);
    let plane = H * H;
    for k in 0..3 {
        // Horizon k + 1 moved k + 1 cells: the last k + 1 columns come from outside (0).
        for c in 0..C {
            for i in 0..H {
                for j in 0..H - (k + 1) {
                    let at = k * C * plane + c * plane + i * H + j;
                    assert!((window.warped[at] - window.future[at]).abs() < 1e-5);
                }
            }
        }
    }
    let scores = HorizonScores::of_window(&window, &window.future, &shape);
    assert!(scores.forecast.iter().all(|v| *v == 0.0));
    for k in 0..3 {
        assert!(scores.ego_warp[k] < scores.copy_last[k], "{scores:?}");
    }
    // The residual the network samples is zero wherever the warp saw the cell.
    let residual = window.diffused();
    assert!(residual[..H - 1].iter().all(|v| v.abs() < 1e-5));

    // A base that fades to 0 at 1 s: frames 0.5 s apart weigh the warp 0.5, then 0 and 0.
    let faded = WindowShape {
        base: EgoWarpBase {
            residual: true,
            fade_s: Some(1.0),
        },
        ..shape
    };
    let window = WindowValues::cut(&sequences.sequences[0], 1, &faded, &actions);
    assert_eq!(window.base_weights, vec![0.5, 0.0, 0.0]);
    let frame = C * plane;
    let (base, diffused) = (window.base(), window.diffused());
    for at in [0, 7, frame - 1] {
        assert!((base[at] - 0.5 * window.warped[at]).abs() < 1e-6);
        assert!((diffused[at] - (window.future[at] - 0.5 * window.warped[at])).abs() < 1e-6);
    }
    assert!(base[frame..].iter().all(|v| *v == 0.0));
    assert_eq!(diffused[frame..], window.future[frame..]);
}

fn train_config(dir: &Path) -> TrainWorldModelConfig {
    let text = std::fs::read_to_string(repo().join("configs/models/train-world-model-tiny.yaml"))
        .expect("read");
    let mut config = TrainWorldModelConfig::from_yaml(&text, "train.yaml").expect("config");
    config.train.latents = dir.join("train");
    config.val.latents = dir.join("val");
    // The paper's three stages; the counterfactual stage has its own test.
    config.stages.truncate(3);
    config.branches = None;
    config.batch = 4;
    config.micro_batch = 2;
    config.optimizer.warmup_steps = 2;
    config.optimizer.lr = 2e-3;
    config.stages[0].context = 2;
    config.stages[0].future = 1;
    config.stages[0].steps = 3;
    config.stages[1].context = 2;
    config.stages[1].future = 2;
    config.stages[1].steps = 3;
    config.stages[2].rate = Rate::Keyframes;
    config.stages[2].stride = 1;
    config.stages[2].context = 2;
    config.stages[2].future = 2;
    config.stages[2].steps = 400;
    config.validation.windows = 2;
    config.validation.sampler.steps = 2;
    config
}

fn training_data(dir: &Path) -> (TrainingData, ActionStats) {
    let sweeps = drive("a", 14, 83_333, 6.0);
    let keyframes = drive("a", 8, 500_000, 2.0);
    write_cache(&dir.join("train"), SWEEPS_INDEX, &sweeps, "abc");
    write_cache(&dir.join("train"), KEYFRAMES_INDEX, &keyframes, "abc");
    let e = expected();
    let sweeps = load_sequences(&dir.join("train"), SWEEPS_INDEX, &e).expect("sweeps");
    let keyframes = load_sequences(&dir.join("train"), KEYFRAMES_INDEX, &e).expect("keyframes");
    let actions = ActionStats::compute(keyframes.actions().iter()).expect("stats");
    let shape = WindowShape {
        context: 2,
        future: 2,
        grid: grid(),
        base: EgoWarpBase {
            residual: true,
            fade_s: None,
        },
        fine: None,
    };
    let validation = vec![WindowValues::cut(
        &keyframes.sequences[0],
        2,
        &shape,
        &actions,
    )];
    (
        TrainingData {
            sweeps,
            keyframes,
            branches: None,
            validation,
        },
        actions,
    )
}

fn trainer(dir: &Path, threads: usize) -> WorldModelTrainer {
    trainer_of(dir, threads, small_model())
}

fn trainer_of(dir: &Path, threads: usize, model: WorldModelConfig) -> WorldModelTrainer {
    let (data, actions) = training_data(dir);
    WorldModelTrainer::new(
        train_config(dir),
        model,
        actions,
        data,
        &Device::flex().autodiff(),
        threads,
    )
    .expect("trainer")
}

fn parameters(trainer: &WorldModelTrainer) -> Vec<f32> {
    use burn::module::{Module, ModuleVisitor, Param};
    struct Collect(Vec<f32>);
    impl ModuleVisitor for Collect {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            self.0
                .extend(param.val().into_data().try_to_vec::<f32>().expect("f32"));
        }
    }
    let mut collect = Collect(Vec::new());
    trainer.shipped_model().visit(&mut collect);
    collect.0
}

#[test]
fn the_stages_run_in_order_and_a_short_sequence_is_overfit() {
    let dir = tempfile::tempdir().expect("dir");
    // The x0 target on the latents themselves: to lower its loss the model must remember the
    // sequence's future, whatever the noise drawn (ε and v also carry the noise's share).
    let mut model = small_model();
    model.diffusion.target = bevworld_world_model::Target::X0;
    model.residual_over_ego_warp = false;
    let mut config = train_config(dir.path());
    config.batch = 8;
    config.micro_batch = 4;
    config.optimizer.lr = 3e-3;
    let (data, actions) = training_data(dir.path());
    let mut trainer =
        WorldModelTrainer::new(config, model, actions, data, &Device::flex().autodiff(), 2)
            .expect("trainer");
    let mut losses = Vec::new();
    for _ in 0..46 {
        let report = trainer.train_step().expect("step");
        assert!(report.loss.is_finite() && report.grad_norm.is_finite());
        losses.push((report.term("stage").expect("stage"), report.loss));
    }
    let stages: Vec<f64> = losses.iter().map(|(s, _)| *s).collect();
    assert_eq!(&stages[..3], &[1.0; 3]);
    assert_eq!(&stages[3..6], &[2.0; 3]);
    assert!(stages[6..].iter().all(|s| *s == 3.0));
    // Stage 3 sees the four windows of one short sequence: a few dozen steps bring its loss
    // well down.
    let first: f64 = losses[6..11].iter().map(|(_, l)| l).sum::<f64>() / 5.0;
    let last: f64 = losses[41..].iter().map(|(_, l)| l).sum::<f64>() / 5.0;
    assert!(last < 0.5 * first, "stage-3 loss {first:.4} -> {last:.4}");
}

#[test]
fn a_step_splits_over_threads_without_changing_a_bit() {
    let dir = tempfile::tempdir().expect("dir");
    let mut one = trainer(dir.path(), 1);
    let mut two = trainer(dir.path(), 2);
    for _ in 0..3 {
        let (a, b) = (
            one.train_step().expect("one"),
            two.train_step().expect("two"),
        );
        assert_eq!(a.loss.to_bits(), b.loss.to_bits());
    }
    assert_eq!(parameters(&one), parameters(&two));
}

#[test]
fn a_resumed_run_continues_bit_for_bit() {
    use bevworld_training::Trainee;
    let dir = tempfile::tempdir().expect("dir");
    let run = dir.path().join("run");
    let mut straight = trainer(dir.path(), 2);
    for _ in 0..4 {
        straight.train_step().expect("step");
    }
    let mut first = trainer(dir.path(), 2);
    for _ in 0..2 {
        first.train_step().expect("step");
    }
    first.save_checkpoint(&run).expect("checkpoint");
    drop(first);
    let mut resumed = trainer(dir.path(), 2).resume(&run).expect("resume");
    assert_eq!(resumed.step(), 2);
    for _ in 0..2 {
        resumed.train_step().expect("step");
    }
    assert_eq!(parameters(&straight), parameters(&resumed));
}

#[test]
fn one_step_lowers_the_loss_on_a_fixed_batch() {
    use bevworld_blocks::init::random_normal;
    use bevworld_blocks::seeded_init;
    use bevworld_world_model::NoiseSchedule;
    use bevworld_world_model::ddim::noisy_and_target;
    use burn::optim::GradientsParams;
    let dir = tempfile::tempdir().expect("dir");
    let config = train_config(dir.path());
    let model_config = small_model();
    let device = Device::flex().autodiff();
    let schedule = NoiseSchedule::new(&model_config.diffusion);
    let mut model = seeded_init(1, &device, |d| model_config.init(d));
    let context = random_normal(2, [2, 2, C, H, H], 0.0, 1.0, &device);
    let future = random_normal(3, [2, 2, C, H, H], 0.0, 0.5, &device);
    let noise = random_normal(4, [2, 2, C, H, H], 0.0, 1.0, &device);
    let actions = random_normal(5, [2, 4, 5], 0.0, 1.0, &device);
    let (noisy, wanted) = noisy_and_target(
        &schedule,
        model_config.diffusion.target,
        future,
        noise,
        &[300, 700],
    );
    let levels = [0.0, 0.0, 300.0, 300.0, 0.0, 0.0, 700.0, 700.0];
    let loss = |model: &bevworld_world_model::WorldModel| {
        let frames = Tensor::cat(vec![context.clone(), noisy.clone()], 1);
        (model.forward(frames, actions.clone(), &levels, 2, None) - wanted.clone())
            .abs()
            .mean()
    };
    let mut optimizer = config.optimizer.adamw();
    let before = loss(&model);
    let value_before = f64::from(before.clone().into_scalar::<f32>());
    let grads = GradientsParams::from_grads(before.backward(), &model);
    model = optimizer.step(1e-3, model, grads);
    let value_after = f64::from(loss(&model).into_scalar::<f32>());
    assert!(
        value_after < value_before,
        "{value_before} -> {value_after}"
    );
}

#[test]
fn ablation_overrides_reach_the_model_config_and_inconsistent_ones_are_refused() {
    use bevworld_world_model_train::moving_weight::MovingWeight;
    use bevworld_world_model_train::{Overrides, TrainRequest, effective_configs};
    let dir = tempfile::tempdir().expect("dir");
    let text = std::fs::read_to_string(repo().join("configs/models/train-world-model-tiny.yaml"))
        .expect("read")
        .replace(
            "model: configs/models/world-model-tiny.yaml",
            &format!(
                "model: {}",
                repo()
                    .join("configs/models/world-model-tiny.yaml")
                    .display()
            ),
        );
    let config = dir.path().join("train.yaml");
    std::fs::write(&config, text).expect("write");
    let request = |overrides: Overrides| TrainRequest {
        config: config.clone(),
        out: dir.path().join("run"),
        resume: false,
        until: None,
        threads: None,
        log_every: 10,
        command: "test".into(),
        overrides,
    };
    let (recipe, shipped) = effective_configs(&request(Overrides::default())).expect("shipped");
    assert!(!shipped.ego_warp_input && shipped.ego_warp_fade_s.is_none());
    // `--init` starts the recipe from weights instead.
    assert_eq!(recipe.init, None);
    let (started, _) = effective_configs(&request(Overrides {
        init: Some(PathBuf::from("runs/other/world-model-tiny.bpk")),
        ..Overrides::default()
    }))
    .expect("an init");
    assert_eq!(
        started.init.as_deref(),
        Some(Path::new("runs/other/world-model-tiny.bpk"))
    );
    // `--moving-weight` weights the loss as the config's `moving_weight` would, checked alike.
    let weight = |extra: f64| MovingWeight {
        extra,
        threshold: 3.0,
    };
    let (weighted, _) = effective_configs(&request(Overrides {
        moving_weight: Some(weight(4.0)),
        ..Overrides::default()
    }))
    .expect("a moving weight");
    assert_eq!(weighted.moving_weight, Some(weight(4.0)));
    let error = effective_configs(&request(Overrides {
        moving_weight: Some(weight(-1.0)),
        ..Overrides::default()
    }))
    .expect_err("a negative extra weight");
    assert!(error.to_string().contains("moving_weight.extra"), "{error}");
    let (_, model) = effective_configs(&request(Overrides {
        ego_warp_input: Some(true),
        ego_warp_fade_s: Some(Some(2.0)),
        ..Overrides::default()
    }))
    .expect("both switches");
    assert!(model.ego_warp_input);
    assert_eq!(model.ego_warp_base().weight(1.0), 0.5);
    let error = effective_configs(&request(Overrides {
        residual_over_ego_warp: Some(false),
        ego_warp_fade_s: Some(Some(2.0)),
        ..Overrides::default()
    }))
    .expect_err("a fade without a residual");
    assert!(error.to_string().contains("ego_warp_fade_s"), "{error}");
    // A loss weighted where the residual moves needs a residual.
    let weighted = std::fs::read_to_string(&config).expect("read")
        + "moving_weight: {extra: 4.0, threshold: 0.25}\n";
    std::fs::write(&config, weighted).expect("write");
    let (train, _) = effective_configs(&request(Overrides::default())).expect("weighted");
    assert_eq!(
        train.moving_weight.map(|w| (w.extra, w.threshold)),
        Some((4.0, 0.25))
    );
    let error = effective_configs(&request(Overrides {
        residual_over_ego_warp: Some(false),
        ..Overrides::default()
    }))
    .expect_err("a moving weight without a residual");
    assert!(
        error.to_string().contains("moving_weight") && error.to_string().contains("residual"),
        "{error}"
    );
    assert!(!dir.path().join("run").exists(), "refused before writing");
}

#[test]
fn a_fine_tune_starts_from_the_weights_it_names_and_refuses_weights_of_other_data() {
    use bevworld_world_model::WeightsMeta;
    use bevworld_world_model::weights::save_weights;
    use bevworld_world_model_train::moving_weight::MovingWeight;
    let dir = tempfile::tempdir().expect("dir");
    let mut trained = trainer(dir.path(), 2);
    for _ in 0..2 {
        trained.train_step().expect("step");
    }
    let (_, actions) = training_data(dir.path());
    let path = dir.path().join("trained.bpk");
    let meta = |action_stats: ActionStats| WeightsMeta {
        model: small_model().name,
        tokenizer_model: "tokenizer-test".into(),
        tokenizer_weights_hash: "abc".into(),
        action_stats,
        steps: 2,
        command: "test".into(),
    };
    save_weights(&trained.shipped_model(), &meta(actions.clone()), &path).expect("save");
    let fresh = trainer(dir.path(), 2);
    assert_ne!(parameters(&fresh), parameters(&trained), "a seeded start");
    let mut tuned = trainer(dir.path(), 2)
        .start_from(&path, Some(("tokenizer-test", "abc")), &actions)
        .expect("start from the weights");
    assert_eq!(
        parameters(&tuned),
        parameters(&trained),
        "the moving average starts there"
    );
    // And trains on, under the weighted loss.
    let mut config = train_config(dir.path());
    config.moving_weight = Some(MovingWeight {
        extra: 4.0,
        threshold: 0.25,
    });
    let report = tuned.train_step().expect("step");
    assert!(report.loss.is_finite());
    let (data, _) = training_data(dir.path());
    let mut weighted = WorldModelTrainer::new(
        config,
        small_model(),
        actions.clone(),
        data,
        &Device::flex().autodiff(),
        2,
    )
    .expect("trainer")
    .start_from(&path, Some(("tokenizer-test", "abc")), &actions)
    .expect("start");
    let report = weighted.train_step().expect("weighted step");
    assert!(report.loss.is_finite() && report.grad_norm > 0.0);
    let moving = report
        .term("moving_share")
        .expect("the share of moving cells");
    assert!((0.0..=1.0).contains(&moving), "{moving}");
    assert_eq!(tuned.train_step().expect("step").term("moving_share"), None);
    // Another tokenizer's latents, or other action statistics: refused, by what differs.
    let error = trainer(dir.path(), 2)
        .start_from(&path, Some(("tokenizer-test", "def")), &actions)
        .err()
        .expect("another tokenizer");
    assert!(error.to_string().starts_with("init:"), "{error}");
    // ... unless the run adapts them to its tokenizer (`init_from_other_tokenizer`).
    let adapted = trainer(dir.path(), 2)
        .start_from(&path, None, &actions)
        .expect("weights of another tokenizer, adapted");
    assert_eq!(parameters(&adapted), parameters(&trained));
    let mut other = actions.clone();
    other.mean[0] += 1.0;
    save_weights(&trained.shipped_model(), &meta(other), &path).expect("save");
    let error = trainer(dir.path(), 2)
        .start_from(&path, Some(("tokenizer-test", "abc")), &actions)
        .err()
        .expect("other action statistics");
    assert!(
        error.to_string().contains("action") || error.to_string().contains("statistics"),
        "{error}"
    );
}

#[test]
fn the_fine_tune_configs_differ_from_each_other_only_where_each_says() {
    let read = |name: &str| {
        let path = repo().join("configs/models").join(name);
        TrainWorldModelConfig::from_yaml_file(&path).expect("a valid config")
    };
    let moving = read("finetune-world-model-moving-tiny.yaml");
    let mut plain = read("finetune-world-model-plain-tiny.yaml");
    let shipped = read("train-world-model-tiny.yaml");
    let mut stop = read("finetune-world-model-stop-tiny.yaml");
    // They start from the recipe's weights, never from the shipped file, which is one of them.
    assert_eq!(
        moving.init.as_deref(),
        Some(Path::new("runs/wm-tiny/world-model-tiny.bpk"))
    );
    // The stop fine-tune adds `stop` to the branched scenes, in caches of their own, and
    // changes nothing else.
    let (stop_branches, plain_branches) = (
        stop.branches.clone().expect("branches"),
        plain.branches.clone().expect("branches"),
    );
    let stop_branch = stop_branches.synth.branch.clone().expect("branched");
    let plain_branch = plain_branches.synth.branch.clone().expect("branched");
    assert_eq!(stop_branch.at_s, plain_branch.at_s);
    assert_eq!(
        stop_branch.manoeuvres,
        [plain_branch.manoeuvres.clone(), vec![Manoeuvre::Stop]].concat()
    );
    assert_ne!(stop_branches.latents, plain_branches.latents);
    assert_ne!(stop_branches.synth.dir, plain_branches.synth.dir);
    assert_eq!(stop_branches.synth.seed, plain_branches.synth.seed);
    stop.branches = plain.branches.clone();
    assert_eq!(stop, plain, "the stop fine-tune changes its branches alone");
    assert!(moving.moving_weight.is_some() && plain.moving_weight.is_none());
    plain.moving_weight = moving.moving_weight;
    assert_eq!(plain, moving, "the ablation changes the loss alone");
    // The same data and scenes as the weights they start from.
    assert_eq!(
        (&moving.train, &moving.val, &moving.test, &moving.branches),
        (
            &shipped.train,
            &shipped.val,
            &shipped.test,
            &shipped.branches
        )
    );
    // The vehicle-tokenizer experiment is the stop fine-tune on another tokenizer's latents,
    // from the shipped weights: the same scenes in caches of their own, nothing else changed.
    let mut vehicles = read("finetune-world-model-vehicles-tiny.yaml");
    let stop = read("finetune-world-model-stop-tiny.yaml");
    assert!(vehicles.init_from_other_tokenizer);
    assert_eq!(
        vehicles.init.as_deref(),
        Some(Path::new("nodes/world_model/weights/world-model-tiny.bpk"))
    );
    assert_ne!(vehicles.tokenizer_weights, stop.tokenizer_weights);
    let mut caches = vec![&mut vehicles.train, &mut vehicles.val];
    caches.extend(vehicles.test.as_mut());
    caches.extend(vehicles.branches.as_mut());
    let stop_caches: Vec<_> = [
        Some(&stop.train),
        Some(&stop.val),
        stop.test.as_ref(),
        stop.branches.as_ref(),
    ]
    .into_iter()
    .flatten()
    .collect();
    assert_eq!(caches.len(), stop_caches.len());
    for (cache, theirs) in caches.into_iter().zip(stop_caches) {
        assert_eq!(cache.synth, theirs.synth, "the same scenes");
        assert_ne!(
            cache.latents, theirs.latents,
            "encoded by another tokenizer"
        );
        cache.latents = theirs.latents.clone();
    }
    vehicles.tokenizer_weights = stop.tokenizer_weights.clone();
    vehicles.init = stop.init.clone();
    vehicles.init_from_other_tokenizer = false;
    assert_eq!(vehicles, stop, "nothing else differs");
    // The fine-token pair: both continue the shipped weights on the stop fine-tune's windows;
    // the fine one's model is the shipped model's with a fine stage, and nothing else differs.
    let mut fine = read("finetune-world-model-fine-tiny.yaml");
    let mut coarse = read("finetune-world-model-coarse-tiny.yaml");
    assert_eq!(
        coarse.init.as_deref(),
        Some(Path::new("nodes/world_model/weights/world-model-tiny.bpk"))
    );
    let model = |path: &Path| WorldModelConfig::from_yaml_file(&repo().join(path)).expect("model");
    let (mut fine_model, coarse_model) = (model(&fine.model), model(&coarse.model));
    assert!(fine_model.fine_tokens.is_some() && coarse_model.fine_tokens.is_none());
    fine_model.fine_tokens = None;
    fine_model.name = coarse_model.name.clone();
    assert_eq!(
        fine_model, coarse_model,
        "the fine model adds its fine stage alone"
    );
    fine.model = coarse.model.clone();
    assert_eq!(fine, coarse, "the ablation drops the fine stage alone");
    coarse.init = stop.init.clone();
    assert_eq!(
        coarse, stop,
        "on the stop fine-tune's windows, from the shipped weights"
    );
}

#[test]
fn a_model_with_fine_tokens_starts_from_its_coarse_weights_and_trains_its_fine_stage() {
    use bevworld_blocks::init::random_normal;
    use bevworld_world_model::weights::save_weights;
    use bevworld_world_model::{FineTokenRule, FineTokenSelection, FineTokensConfig, WeightsMeta};
    let dir = tempfile::tempdir().expect("dir");
    let mut coarse = trainer(dir.path(), 2);
    coarse.train_step().expect("step");
    let (_, actions) = training_data(dir.path());
    let path = dir.path().join("coarse.bpk");
    let meta = WeightsMeta {
        model: small_model().name,
        tokenizer_model: "tokenizer-test".into(),
        tokenizer_weights_hash: "abc".into(),
        action_stats: actions.clone(),
        steps: 1,
        command: "test".into(),
    };
    save_weights(&coarse.shipped_model(), &meta, &path).expect("save");
    let fine_model = |width: usize| {
        let mut c = small_model();
        c.name = "world-model-fine-test".into();
        c.width = width;
        c.fine_tokens = Some(FineTokensConfig {
            width: 16,
            depth: 1,
            heads: 2,
            select: FineTokenRule {
                threshold: 0.0,
                dilate: 0,
            },
        });
        c
    };
    let mut fine = trainer_of(dir.path(), 2, fine_model(32))
        .start_from(&path, Some(("tokenizer-test", "abc")), &actions)
        .expect("a fine model from its coarse weights");
    // It starts as the coarse model, every token opened.
    let config = fine_model(32);
    let device = Device::flex();
    let frames = config.context_frames + config.future_frames;
    let latents = random_normal(1, [1, frames, C, H, H], 0.0, 1.0, &device);
    let actions_in = random_normal(2, [1, frames, 5], 0.0, 1.0, &device);
    let levels = [0.0, 0.0, 300.0, 300.0];
    let every = FineTokenSelection {
        tokens: vec![(0..16).collect()],
    };
    let predict = |trainer: &WorldModelTrainer, selection: &FineTokenSelection| {
        trainer
            .shipped_model()
            .forward_selected(
                latents.clone(),
                actions_in.clone(),
                &levels,
                2,
                None,
                selection,
            )
            .into_data()
            .try_to_vec::<f32>()
            .expect("f32")
    };
    assert_eq!(
        predict(&fine, &every),
        predict(&coarse, &FineTokenSelection::none(1))
    );
    // Its steps open the tokens where the hand-made scene moves, and move the fine stage.
    let report = fine.train_step().expect("step");
    let share = report
        .term("fine_share")
        .expect("the share of tokens opened");
    assert!(share > 0.0 && share <= 1.0, "{share}");
    assert_ne!(
        predict(&fine, &every),
        predict(&fine, &FineTokenSelection::none(1))
    );
    assert_eq!(coarse.train_step().expect("step").term("fine_share"), None);
    // Coarse weights of another size are refused by the weights file, naming it.
    let error = trainer_of(dir.path(), 2, fine_model(64))
        .start_from(&path, Some(("tokenizer-test", "abc")), &actions)
        .err()
        .expect("a coarse model of another width");
    assert!(error.to_string().contains("coarse.bpk"), "{error}");
}
