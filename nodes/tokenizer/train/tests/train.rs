//! Training, checked on a tiny synthetic scene: a step lowers the loss of a fixed batch, 60
//! steps overfit one frame, a resumed run equals an uninterrupted one bit for bit, a
//! non-finite loss is refused without touching the trainable parameters, and configs, schedules and
//! checkpoints behave as documented.

use std::path::PathBuf;
use std::sync::OnceLock;

use bevworld_sensors::synth::{SynthConfig, generate};
use bevworld_tokenizer::{EncoderArrays, FrameInputs, Modality, TokenizerConfig};
use bevworld_tokenizer_train::data::{TrainingFrame, load_frames};
use bevworld_tokenizer_train::{
    StepReport, Term, TrainConfig, TrainError, Trainer, ValidationReport,
};
use bevworld_training::checkpoint;
use bevworld_training::schedule::learning_rate;
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;

fn root() -> PathBuf {
    PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .join("../../..")
}

fn configs() -> (TrainConfig, TokenizerConfig) {
    TrainConfig::from_yaml_file(&root().join("configs/models/train-tokenizer-tiny.yaml"))
        .expect("the shipped training config")
}

/// One synthetic scene of `seconds` with the tiny model's camera size, in a new temporary
/// folder (kept alive by the returned guard).
fn small_scene(seed: u64, seconds: f64) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("synth");
    let config = SynthConfig {
        seed,
        scenes: 1,
        seconds,
        camera_width: 112,
        camera_height: 64,
        ..Default::default()
    };
    generate(&data, &config, |_, _| {}).expect("synthetic scene");
    (dir, data)
}

/// Two keyframes of a 1-second synthetic scene with small cameras, prepared once per test
/// binary (the folder lives as long as the process).
fn frames() -> &'static Vec<TrainingFrame> {
    static FRAMES: OnceLock<(tempfile::TempDir, Vec<TrainingFrame>)> = OnceLock::new();
    &FRAMES
        .get_or_init(|| {
            let (dir, data) = small_scene(77, 1.0);
            let (_, model) = configs();
            let frames =
                load_frames(&data, &FrameInputs::new(&model), 2, |_, _| {}).expect("frames");
            (dir, frames)
        })
        .1
}

/// A trainer on the flex device, validating on its training frames.
fn trainer(config: TrainConfig, model: TokenizerConfig, frames: Vec<TrainingFrame>) -> Trainer {
    Trainer::new(config, model, &Device::flex(), frames.clone(), frames).expect("trainer")
}

/// A trainer on the first frame only, with every camera and every LiDAR ray each step: the
/// batch is the same at every step.
fn fixed_batch_trainer(lr: f64) -> Trainer {
    let (mut config, model) = configs();
    config.optimizer.lr = lr;
    config.optimizer.warmup_steps = 0;
    config.optimizer.final_lr_fraction = 1.0;
    config.rays.cameras_per_step = 6;
    config.rays.lidar_rays = usize::MAX;
    config.steps = 1000;
    // The last iterate is validated: these tests are about what the steps themselves learn.
    config.ema_decay = None;
    let one = vec![frames()[0].clone()];
    trainer(config, model, one.clone())
}

#[test]
fn one_step_lowers_the_loss_of_a_fixed_batch() {
    let mut trainer = fixed_batch_trainer(1e-3);
    let first = trainer.train_step().expect("step 1");
    let second = trainer.train_step().expect("step 2");
    assert!(
        second.loss < first.loss,
        "loss {} then {}",
        first.loss,
        second.loss
    );
    assert!(first.grad_norm > 0.0 && first.grad_norm.is_finite());
}

#[test]
fn a_hundred_steps_on_one_frame_fit_it() {
    let mut trainer = fixed_batch_trainer(5e-3);
    let before = trainer.validate().expect("validation");
    // Not overfitting, which takes thousands of steps (tokenizer-training.md's nuScenes fit):
    // the same frame, step after step, must be fitted fast. With the tiny config's 1/4 camera
    // rays it goes 15.5 -> 18.0 dB in 80 steps and 18.5 dB in 100 (16.9 dB at step 60); the
    // bar, +2.5 dB, fails a step that learns at half that rate.
    for _ in 0..100 {
        trainer.train_step().expect("step");
    }
    let after = trainer.validate().expect("validation");
    let psnr = |v: &ValidationReport| v.psnr_db.expect("the full model renders cameras");
    let chamfer = |v: &ValidationReport| v.chamfer_m2.expect("the full model renders LiDAR");
    assert!(
        psnr(&after) > psnr(&before) + 2.5,
        "PSNR {:.2} -> {:.2} dB",
        psnr(&before),
        psnr(&after)
    );
    assert!(
        chamfer(&after) < chamfer(&before),
        "Chamfer {:.2} -> {:.2} m²",
        chamfer(&before),
        chamfer(&after)
    );
}

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
    module.valid().visit(&mut collect);
    collect.0
}

/// The tokenizer's, the discriminator's and the weight average's values.
fn values(trainer: &Trainer) -> Vec<f32> {
    let mut all = module_values(trainer.model());
    all.extend(module_values(trainer.discriminator()));
    if let Some(average) = trainer.weight_average() {
        all.extend(module_values(average));
    }
    all
}

/// The latent of a fixed frame on the training device: it depends on the trainable parameters
/// alone.
fn training_latent(trainer: &Trainer, frame: &TrainingFrame) -> Vec<f32> {
    let device = Device::flex().autodiff();
    trainer
        .model()
        .encode(frame.encoder.to_input(&device))
        .latent
        .into_data()
        .try_to_vec::<f32>()
        .expect("latent")
}

#[test]
fn frames_spread_over_threads_give_the_run_one_thread_gives() {
    let (mut config, model) = configs();
    config.steps = 3;
    config.frames_per_step = 3;
    // The GAN from the second step on: the generator term runs on the workers' discriminator
    // replicas, and the discriminator steps on every frame's cameras.
    config.loss.gan_start = 1;
    config.rays.lidar_rays = 256;
    config.rays.cameras_per_step = 2;
    let frames = frames().clone();
    let _dir = tempfile::tempdir().expect("tempdir");
    // Both start from the config's seed: the same weights, whatever the other tests of this
    // binary draw meanwhile (initialisation is seeded per model).
    let mut one = trainer(config.clone(), model.clone(), frames.clone()).with_threads(1);
    let mut two = trainer(config, model, frames).with_threads(2);
    assert_eq!((one.threads(), two.threads()), (1, 2));
    assert!(
        values(&one)
            .iter()
            .zip(&values(&two))
            .all(|(x, y)| x.to_bits() == y.to_bits()),
        "one seed gave two sets of initial weights"
    );
    for step in 1..=3 {
        let (a, b) = (
            one.train_step().expect("one thread"),
            two.train_step().expect("two threads"),
        );
        assert_eq!(a, b, "step {step}");
    }
    let (a, b) = (values(&one), values(&two));
    assert_eq!(a.len(), b.len());
    assert!(
        a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
        "parameters differ between one and two threads"
    );
    assert_eq!(
        one.validate().expect("validation"),
        two.validate().expect("validation")
    );
}

#[test]
fn a_resumed_run_equals_an_uninterrupted_one() {
    let (mut config, model) = configs();
    config.steps = 4;
    // The GAN from the second step on, so that the discriminator and its optimiser resume too.
    config.loss.gan_start = 1;
    config.rays.lidar_rays = 256;
    config.rays.cameras_per_step = 2;
    let frames = frames().clone();
    let dir = tempfile::tempdir().expect("tempdir");

    // The committed config keeps a moving average of the weights; it resumes too.
    assert!(config.ema_decay.is_some());
    let mut straight = trainer(config.clone(), model.clone(), frames.clone());
    // Both runs start from the same parameters: the second loads the first's step-0 state
    // (initialisation draws from a device RNG that parallel tests share).
    let start = dir.path().join("start");
    straight.save_checkpoint(&start).expect("step-0 checkpoint");
    for _ in 0..4 {
        straight.train_step().expect("step");
    }

    let run = dir.path().join("run");
    let mut first = trainer(config.clone(), model.clone(), frames.clone())
        .resume(&start)
        .expect("resume from step 0");
    first.train_step().expect("step");
    first.train_step().expect("step");
    first.save_checkpoint(&run).expect("checkpoint");
    // A later step that never reached a checkpoint is lost, as after a crash.
    first.train_step().expect("step");
    drop(first);
    let mut resumed = trainer(config, model, frames.clone())
        .resume(&run)
        .expect("resume");
    assert_eq!(resumed.step(), 2);
    resumed.train_step().expect("step");
    resumed.train_step().expect("step");

    let (a, b) = (values(&straight), values(&resumed));
    assert_eq!(a.len(), b.len());
    let differing = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| x.to_bits() != y.to_bits())
        .count();
    assert_eq!(
        differing,
        0,
        "{differing} of {} values differ after resuming",
        a.len()
    );
}

#[test]
fn a_non_finite_loss_is_refused_and_changes_nothing() {
    let (config, model) = configs();
    let mut frame = frames()[0].clone();
    frame.lidar_ranges.iter_mut().for_each(|r| *r = f32::NAN);
    let mut trainer = trainer(config, model, vec![frame.clone()]);
    let before = training_latent(&trainer, &frame);
    match trainer.train_step() {
        Err(TrainError::NonFinite { step, what, .. }) => {
            assert_eq!((step, what), (1, "LiDAR loss"));
        }
        other => panic!("expected a refused step, got {other:?}"),
    }
    assert_eq!(trainer.step(), 0);
    assert_eq!(
        before,
        training_latent(&trainer, &frame),
        "the parameters moved"
    );
}

#[test]
fn bad_training_configs_name_every_field() {
    let (mut config, _) = configs();
    assert!(config.problems().is_empty(), "{:?}", config.problems());
    config.optimizer.lr = -1.0;
    config.optimizer.beta_2 = 1.0;
    config.rays.lidar_rays = 0;
    config.data.val.seed = config.data.train.seed + 3;
    config.frames_per_step = 0;
    config.loss.lidar_distortion = f64::NAN;
    config.loss.lidar_termination = -0.5;
    config.loss.rgb_l2 = f64::INFINITY;
    config.optimizer.decay_steps = Some(0);
    config.ema_decay = Some(1.0);
    config.rays.lidar_vehicle_share = 1.5;
    config.loss.density_sparsity = -0.01;
    // A decoder fine-tune with no weights to take the encoder from.
    config.init = None;
    config.trains = bevworld_tokenizer_train::TrainedParts::Decoder;
    let problems = config
        .problems()
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("\n");
    for field in [
        "optimizer.lr",
        "optimizer.beta_2",
        "rays.lidar_rays",
        "data.val.seed",
        "frames_per_step",
        "loss.lidar_distortion",
        "loss.lidar_termination",
        "loss.rgb_l2",
        "optimizer.decay_steps",
        "ema_decay",
        "rays.lidar_vehicle_share",
        "loss.density_sparsity",
        "trains",
    ] {
        assert!(
            problems.contains(field),
            "{field} missing from:\n{problems}"
        );
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("bad.yaml");
    std::fs::write(&path, "model: tokenizer-tiny.yaml\nsteps: ten\n").expect("write");
    let message = TrainConfig::from_yaml_file(&path)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("bad.yaml") && message.contains("steps"),
        "{message}"
    );
    // An unknown way of drawing LiDAR rays names the file and the value.
    let shipped = std::fs::read_to_string(root().join("configs/models/train-tokenizer-tiny.yaml"))
        .expect("shipped config");
    assert!(shipped.contains("lidar_draw: uniform"));
    let path = dir.path().join("bad-draw.yaml");
    std::fs::write(
        &path,
        shipped.replace("lidar_draw: uniform", "lidar_draw: nearest"),
    )
    .expect("write");
    let message = TrainConfig::from_yaml_file(&path)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("bad-draw.yaml") && message.contains("nearest"),
        "{message}"
    );
    // An unknown part to train names the file and the value.
    let path = dir.path().join("bad-trains.yaml");
    std::fs::write(&path, format!("trains: encoder\n{shipped}")).expect("write");
    let message = TrainConfig::from_yaml_file(&path)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("bad-trains.yaml") && message.contains("encoder"),
        "{message}"
    );
}

#[test]
fn decay_steps_stops_a_run_part_way_down_a_longer_cosine() {
    let (mut config, model) = configs();
    config.optimizer.warmup_steps = 0;
    config.optimizer.decay_steps = Some(4);
    config.steps = 2;
    config.rays.lidar_rays = 64;
    config.rays.cameras_per_step = 1;
    let (lr, floor) = (config.optimizer.lr, config.optimizer.final_lr_fraction);
    let mut run = trainer(config, model, frames().clone());
    let rates: Vec<f64> = (0..2).map(|_| run.train_step().expect("step").lr).collect();
    assert!(run.is_done());
    // Steps 0 and 1 of a 4-step cosine: the peak, then ½(1 + cos(π/4)) of the way from the
    // floor to it; a 2-step schedule would have stepped at the peak and half way down.
    let second = lr * (floor + (1.0 - floor) * 0.5 * (1.0 + std::f64::consts::FRAC_1_SQRT_2));
    assert!((rates[0] - lr).abs() < 1e-15, "{rates:?}");
    assert!(
        (rates[1] - second).abs() < 1e-15,
        "{rates:?} against {second}"
    );
    assert!((learning_rate(lr, 0, 2, floor, 1) - rates[1]).abs() > 1e-5);
}

#[test]
fn the_committed_decay_horizon_survives_the_run_folders_copy_of_the_config() {
    // A resumed run reads the config its run folder recorded, so the horizon must be written.
    let (config, _) = configs();
    let horizon = config
        .optimizer
        .decay_steps
        .expect("the committed config sets decay_steps");
    assert!(horizon > config.steps, "{horizon} <= {}", config.steps);
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("train.yaml");
    std::fs::write(&path, config.to_yaml().expect("yaml")).expect("write");
    let (again, _) = TrainConfig::from_yaml_file(&path).expect("reads back");
    assert_eq!(again.optimizer.decay_steps, Some(horizon));
    // Absent, it is the run's own length, and stays absent.
    let mut plain = config.clone();
    plain.optimizer.decay_steps = None;
    assert!(!plain.to_yaml().expect("yaml").contains("decay_steps"));
}

#[test]
fn checkpoints_keep_the_newest_and_ignore_partial_ones() {
    let mut trainer = fixed_batch_trainer(1e-3);
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path();
    assert!(matches!(
        checkpoint::latest(run),
        Err(checkpoint::CheckpointError::None { .. })
    ));
    for _ in 0..5 {
        trainer.train_step().expect("step");
        trainer.save_checkpoint(run).expect("checkpoint");
    }
    // keep_checkpoints is 3 in the shipped config.
    let mut names: Vec<String> = std::fs::read_dir(checkpoint::checkpoints_dir(run))
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().to_string())
        .collect();
    names.sort();
    assert_eq!(
        names,
        ["latest", "step-0000003", "step-0000004", "step-0000005"]
    );
    // A crash mid-write leaves a .partial folder, which is never taken for a checkpoint.
    std::fs::create_dir_all(checkpoint::checkpoints_dir(run).join("step-0000006.partial"))
        .expect("mkdir");
    let (_, state) = checkpoint::latest(run).expect("latest");
    assert_eq!(state.step, 5);
}

#[test]
fn the_shipped_training_configs_load() {
    for name in ["tiny", "paper"] {
        let path = root().join(format!("configs/models/train-tokenizer-{name}.yaml"));
        let (config, model) = TrainConfig::from_yaml_file(&path).expect("loads");
        assert!(config.problems().is_empty());
        assert_eq!(model.name, format!("tokenizer-{name}"));
    }
    // The sparse fine-tune: the shipped weights' decoder, with the prior.
    let (sparse, model) = TrainConfig::from_yaml_file(
        &root().join("configs/models/finetune-tokenizer-sparse-tiny.yaml"),
    )
    .expect("the sparse fine-tune config");
    assert_eq!(model, configs().1);
    assert_eq!(
        sparse.trains,
        bevworld_tokenizer_train::TrainedParts::Decoder
    );
    assert!(sparse.loss.density_sparsity > 0.0);
    let init = sparse.init.expect("a fine-tune starts from weights");
    assert!(root().join(&init).is_file(), "{}", init.display());
}

/// The vehicle fine-tune is the recipe but for its start, its length and rate, and the share
/// of rays on vehicles: a difference it measures is one of those.
#[test]
fn the_vehicle_fine_tune_differs_from_the_recipe_only_where_it_says() {
    let (mut recipe, recipe_model) = configs();
    let (finetune, finetune_model) = TrainConfig::from_yaml_file(
        &root().join("configs/models/finetune-tokenizer-vehicles-tiny.yaml"),
    )
    .expect("the fine-tune config");
    assert_eq!(finetune_model, recipe_model);
    let init = finetune
        .init
        .clone()
        .expect("a fine-tune starts from weights");
    assert!(
        root().join(&init).is_file(),
        "{} is not the shipped weights' path",
        init.display()
    );
    recipe.init = Some(init);
    recipe.steps = 1000;
    recipe.seed = 1;
    recipe.optimizer.lr = 7e-4;
    recipe.optimizer.warmup_steps = 50;
    recipe.optimizer.decay_steps = None;
    recipe.rays.lidar_vehicle_share = 0.25;
    recipe.checkpoint_every = 250;
    recipe.validate_every = 500;
    assert_eq!(finetune, recipe);
}

/// A car 10 m ahead (4 m long, 2 m wide, 1.5 m tall) and a pedestrian 10 m to the left, and
/// five returns worked out by hand against them.
#[test]
fn the_returns_on_vehicles_are_those_inside_their_boxes_by_hand() {
    use bevworld_sensors::{Dataset, DatasetOptions};
    use bevworld_tokenizer::render::rays::Rays;
    use bevworld_types::ObjectBox;
    use glam::{DAffine3, DVec3};

    let (_dir, data) = small_scene(79, 0.5);
    let mut frame = Dataset::open(&data, &DatasetOptions::default())
        .expect("scene")
        .read(0)
        .expect("frame 0");
    let global_from_ego = frame.lidar.global_from_ego;
    let object = |category: &str, at: [f64; 3], size: [f64; 3]| ObjectBox {
        instance_token: category.into(),
        category: category.into(),
        global_from_box: global_from_ego * DAffine3::from_translation(DVec3::from_array(at)),
        size,
        velocity: Some([0.0, 0.0]),
        attributes: Vec::new(),
        num_pts: 1,
    };
    frame.boxes = vec![
        object("vehicle.car", [10.0, 0.0, 0.75], [2.0, 4.0, 1.5]),
        object("human.pedestrian.adult", [0.0, 10.0, 0.9], [0.6, 0.6, 1.8]),
    ];
    let returns: [[f32; 3]; 5] = [
        [10.0, 0.0, 1.0],  // inside the car
        [10.0, 0.0, 0.05], // under it, below the box's lifted bottom: the road
        [20.0, 0.0, 1.0],  // past it
        [0.0, 10.0, 1.0],  // on the pedestrian, who is no vehicle
        [9.0, 1.15, 1.0],  // 0.15 m off its side, within the 0.2 m margin
    ];
    let ranges: Vec<f32> = returns
        .iter()
        .map(|p| p.iter().map(|v| v * v).sum::<f32>().sqrt())
        .collect();
    let rays = Rays {
        origins: vec![[0.0; 3]; returns.len()],
        directions: returns
            .iter()
            .zip(&ranges)
            .map(|(p, r)| p.map(|v| v / r))
            .collect(),
    };
    assert_eq!(
        bevworld_tokenizer_train::data::on_vehicles(&frame, &rays, &ranges),
        vec![0, 4]
    );
    frame.boxes.clear();
    assert!(bevworld_tokenizer_train::data::on_vehicles(&frame, &rays, &ranges).is_empty());
}

#[test]
fn a_share_of_the_lidar_rays_is_drawn_from_the_vehicles_and_none_leaves_the_draw_as_it_was() {
    use bevworld_tokenizer_train::data::draw_lidar;
    use bevworld_types::SplitMix64;

    let (config, _) = configs();
    let mut frame = frames()[0].clone();
    let on_vehicles = frame.lidar_on_vehicles.clone();
    assert!(
        on_vehicles.len() > 100 && on_vehicles.len() < frame.lidar.len() / 4,
        "{} of {} returns on vehicles",
        on_vehicles.len(),
        frame.lidar.len()
    );
    let mut rays = config.rays.clone();
    rays.lidar_rays = 400;
    let n = frame.lidar.len();

    // No share: the base draw, and the random stream left where it leaves it.
    rays.lidar_vehicle_share = 0.0;
    let (mut rng, mut base) = (SplitMix64::new(5), SplitMix64::new(5));
    assert_eq!(draw_lidar(&mut rng, &frame, &rays), base.choose(n, 400));
    assert_eq!(rng.next_u64(), base.next_u64());

    // A quarter: 300 by the base draw, then 100 distinct returns on vehicles.
    rays.lidar_vehicle_share = 0.25;
    let (mut rng, mut base) = (SplitMix64::new(5), SplitMix64::new(5));
    let drawn = draw_lidar(&mut rng, &frame, &rays);
    assert_eq!(drawn.len(), 400);
    assert_eq!(drawn[..300], base.choose(n, 300)[..]);
    let mut from_vehicles = drawn[300..].to_vec();
    assert!(from_vehicles.iter().all(|i| on_vehicles.contains(i)));
    from_vehicles.sort_unstable();
    from_vehicles.dedup();
    assert_eq!(from_vehicles.len(), 100);

    // All of them, when a frame has fewer returns on vehicles than the share asks for.
    rays.lidar_vehicle_share = 1.0;
    rays.lidar_rays = on_vehicles.len() + 10;
    let drawn = draw_lidar(&mut SplitMix64::new(5), &frame, &rays);
    assert_eq!(drawn.len(), on_vehicles.len() + 10);
    let mut tail = drawn[10..].to_vec();
    tail.sort_unstable();
    assert_eq!(tail, on_vehicles);

    // A frame without annotated vehicles draws as with no share.
    frame.lidar_on_vehicles.clear();
    rays.lidar_rays = 400;
    assert_eq!(
        draw_lidar(&mut SplitMix64::new(5), &frame, &rays),
        SplitMix64::new(5).choose(n, 400)
    );
}

#[test]
fn a_fine_tune_starts_from_its_weights_and_a_missing_file_is_refused_before_any_data() {
    let (mut config, model) = configs();
    config.rays.lidar_rays = 256;
    config.rays.cameras_per_step = 2;
    let mut first = trainer(config.clone(), model.clone(), frames().clone());
    first.train_step().expect("step");
    let dir = tempfile::tempdir().expect("tempdir");
    let weights = dir.path().join("tokenizer.bpk");
    first.save_weights(&weights).expect("weights");
    let saved = module_values(
        &bevworld_tokenizer::load_weights(&model, &weights, &Device::flex()).expect("load"),
    );
    let started = trainer(config.clone(), model.clone(), frames().clone())
        .start_from(&weights)
        .expect("the weights load");
    assert_eq!(module_values(started.model()), saved);
    assert_eq!(
        module_values(started.weight_average().expect("kept")),
        saved
    );
    assert_ne!(
        values(&trainer(config.clone(), model.clone(), frames().clone())),
        values(&started),
        "the seeded start is another"
    );

    // A run whose `init` is missing is refused by that field, before it looks for its data
    // (here a folder that is not there either) or makes its run folder.
    let shipped = std::fs::read_to_string(root().join("configs/models/train-tokenizer-tiny.yaml"))
        .expect("shipped config");
    // The model config named by its full path, so that the file can live in a temporary folder.
    let model_path = root().join("configs/models/tokenizer-tiny.yaml");
    assert!(shipped.contains("model: tokenizer-tiny.yaml"));
    let path = dir.path().join("missing-init.yaml");
    std::fs::write(
        &path,
        format!(
            "init: {}\n{}",
            dir.path().join("gone.bpk").display(),
            shipped.replace(
                "model: tokenizer-tiny.yaml",
                &format!("model: {}", model_path.display())
            )
        ),
    )
    .expect("write");
    let out = dir.path().join("run");
    let request = bevworld_tokenizer_train::TrainRequest {
        config: path,
        out: out.clone(),
        resume: false,
        overrides: bevworld_tokenizer_train::Overrides::default(),
        until: None,
        data: Some(dir.path().join("no-data")),
        val: Some(dir.path().join("no-data")),
        threads: None,
        log_every: 10,
        targets: bevworld_tokenizer_train::Targets::default(),
    };
    let message = match bevworld_tokenizer_train::train(&request, &Device::flex(), &mut ()) {
        Err(error) => error.to_string(),
        Ok(_) => panic!("a missing init was accepted"),
    };
    assert!(
        message.contains("init") && message.contains("gone.bpk"),
        "{message}"
    );
    assert!(!out.exists(), "a refused run made its folder");
}

#[test]
fn the_gan_switches_on_at_the_configured_step() {
    let (mut config, model) = configs();
    config.loss.gan_start = 2;
    config.rays.lidar_rays = 128;
    let frames = frames().clone();
    let mut trainer = trainer(config, model, frames.clone());
    let initial = module_values(trainer.discriminator());
    for step in 1..=2 {
        assert!(!trainer.gan_active() || step > 2);
        let report = trainer.train_step().expect("step");
        assert_eq!(
            (report.term(Term::Gan), report.term(Term::Discriminator)),
            (None, None),
            "step {step}"
        );
    }
    assert_eq!(
        initial,
        module_values(trainer.discriminator()),
        "the discriminator moved during warm-up"
    );
    assert!(trainer.gan_active());
    let report = trainer.train_step().expect("step 3");
    let (gan, disc) = (
        report.term(Term::Gan).expect("gan term"),
        report.term(Term::Discriminator).expect("disc loss"),
    );
    assert!(
        gan.is_finite() && disc.is_finite() && disc >= 0.0,
        "{gan} {disc}"
    );
    // The total is the weighted sum of its parts.
    let w = &trainer.config.loss;
    let expected = w.rgb_l1 * report.term(Term::Rgb).expect("rgb")
        + w.rgb_l2 * report.term(Term::RgbSquared).expect("squared rgb")
        + w.lidar_l1 * report.term(Term::Lidar).expect("lidar")
        + w.lidar_distortion * report.term(Term::Distortion).expect("distortion")
        + w.gan_generator * gan;
    assert!(
        (report.loss - expected).abs() < 1e-4 * (1.0 + expected.abs()),
        "{} vs {expected}",
        report.loss
    );
    assert_ne!(
        initial,
        module_values(trainer.discriminator()),
        "the discriminator did not learn"
    );
}

#[test]
fn the_perceptual_term_needs_weights_and_joins_the_loss_when_given() {
    let (config, model) = configs();
    let frames = frames().clone();
    // Off without weights: the step reports no perceptual term.
    let mut off = trainer(config.clone(), model.clone(), frames.clone());
    assert_eq!(off.train_step().expect("step").term(Term::Perceptual), None);

    let mut missing = config.clone();
    missing.perceptual_weights = Some("/nonexistent/vgg16-397923af.pth".into());
    let message = match Trainer::new(
        missing,
        model.clone(),
        &Device::flex(),
        frames.clone(),
        frames.clone(),
    ) {
        Err(error) => error.to_string(),
        Ok(_) => panic!("a missing VGG16 file was accepted"),
    };
    assert!(
        message.contains("/nonexistent/vgg16-397923af.pth"),
        "{message}"
    );

    let dir = tempfile::tempdir().expect("tempdir");
    let vgg = dir.path().join("vgg16.safetensors");
    bevworld_tokenizer_train::perceptual::save_torchvision_layout(
        &bevworld_tokenizer_train::perceptual::Vgg16Features::init_unloaded(&Device::flex()),
        &vgg,
    )
    .expect("save");
    let mut with = config;
    with.perceptual_weights = Some(vgg);
    let mut on = trainer(with, model, frames.clone());
    let report = on.train_step().expect("step");
    let term = report.term(Term::Perceptual).expect("perceptual term");
    let w = &on.config.loss;
    let expected = w.rgb_l1 * report.term(Term::Rgb).expect("rgb")
        + w.rgb_l2 * report.term(Term::RgbSquared).expect("squared rgb")
        + w.lidar_l1 * report.term(Term::Lidar).expect("lidar")
        + w.lidar_distortion * report.term(Term::Distortion).expect("distortion")
        + w.perceptual * term;
    assert!(
        term > 0.0 && (report.loss - expected).abs() < 1e-4 * (1.0 + expected),
        "{} vs {expected}",
        report.loss
    );
}

/// One step with a loss term's weight at 0 and one at `weight`, from the same seed, so both
/// draw the same rays (256 LiDAR rays a frame).
fn steps_without_and_with(
    set_weight: impl Fn(&mut TrainConfig, f64),
    weight: f64,
) -> (StepReport, StepReport) {
    let (mut config, model) = configs();
    config.rays.lidar_rays = 256;
    set_weight(&mut config, 0.0);
    let without = trainer(config.clone(), model.clone(), frames().clone())
        .train_step()
        .expect("step");
    set_weight(&mut config, weight);
    let with = trainer(config, model, frames().clone())
        .train_step()
        .expect("step");
    (without, with)
}

/// The RGB, LiDAR and distortion terms of two steps over the same rays are equal: adding a
/// term leaves the others alone.
fn assert_terms_unchanged(without: &StepReport, with: &StepReport) {
    for term in [Term::Rgb, Term::Lidar, Term::Distortion] {
        assert_eq!(with.term(term), without.term(term), "{term:?}");
    }
}

/// The total of `with` is that of `without` plus the weighted term alone.
fn assert_total_grows_by(without: &StepReport, with: &StepReport, weighted_term: f64) {
    let expected = without.loss + weighted_term;
    assert!(
        (with.loss - expected).abs() < 1e-5 * (1.0 + expected),
        "{} vs {expected}",
        with.loss
    );
}

#[test]
fn the_distortion_term_joins_the_loss_only_when_weighted() {
    assert_eq!(
        configs().0.loss.lidar_distortion,
        0.1,
        "on in the shipped config"
    );
    let (without, with) = steps_without_and_with(|c, w| c.loss.lidar_distortion = w, 0.1);
    assert_eq!(without.term(Term::Distortion), None);
    let term = with.term(Term::Distortion).expect("distortion term");
    // A ray's weights are non-negative and sum to at most 1, so its distortion lies in
    // [0, 1); an untrained field spreads them, so it is above 0.
    assert!(term > 0.0 && term < 1.0, "{term}");
    // The same rays: the other terms are unchanged.
    assert_eq!(
        (with.term(Term::Rgb), with.term(Term::Lidar)),
        (without.term(Term::Rgb), without.term(Term::Lidar))
    );
    assert_total_grows_by(&without, &with, 0.1 * term);
}

#[test]
fn the_termination_term_joins_the_loss_only_when_weighted() {
    let (without, with) = steps_without_and_with(|c, w| c.loss.lidar_termination = w, 0.05);
    assert_eq!(without.term(Term::Termination), None);
    let term = with.term(Term::Termination).expect("termination term");
    // A ray's negative log-likelihood lies in [0, −ln 1e-6]; an untrained field stops its
    // rays near the car, far from most returns, so it is well above ln 2.
    assert!(term > 1.0 && term < 13.82, "{term}");
    // The same rays: the other terms are unchanged.
    assert_terms_unchanged(&without, &with);
    assert_total_grows_by(&without, &with, 0.05 * term);
}

#[test]
fn the_squared_rgb_term_joins_the_loss_only_when_weighted() {
    let weight = 5.0;
    let (without, with) = steps_without_and_with(|c, w| c.loss.rgb_l2 = w, weight);
    // The same rays and the same L1 terms; the squared term is reported only when weighted.
    assert_terms_unchanged(&without, &with);
    assert_eq!(without.term(Term::RgbSquared), None);
    let mean_squared = with.term(Term::RgbSquared).expect("squared RGB term");
    // The step's total grows by the weighted term it reports.
    assert_total_grows_by(&without, &with, weight * mean_squared);
    let mean_abs = with.term(Term::Rgb).expect("RGB term");
    // Rendered and input colours lie in [0, 1], so every error e has e² <= |e|; and
    // mean(e²) >= mean(|e|)², per frame and again over the step's frames (Jensen).
    assert!(
        mean_squared <= mean_abs * (1.0 + 1e-4)
            && mean_squared >= mean_abs * mean_abs * (1.0 - 1e-4),
        "mean squared {mean_squared} against mean absolute {mean_abs}"
    );
}

#[test]
fn a_damaged_checkpoint_is_an_error_naming_the_file() {
    let mut trainer = fixed_batch_trainer(1e-3);
    trainer.train_step().expect("step");
    let dir = tempfile::tempdir().expect("tempdir");
    let saved = trainer.save_checkpoint(dir.path()).expect("checkpoint");
    let state = std::fs::read(saved.join("state.json")).expect("state");
    std::fs::write(saved.join("state.json"), "{\"step\": \"two\"}").expect("write");
    let message = match fixed_batch_trainer(1e-3).resume(dir.path()) {
        Err(error) => error.to_string(),
        Ok(_) => panic!("a damaged state.json was accepted"),
    };
    assert!(message.contains("state.json"), "{message}");
    std::fs::write(saved.join("state.json"), &state).expect("restore");
    std::fs::remove_file(saved.join("model.bpk")).expect("remove");
    let message = match fixed_batch_trainer(1e-3).resume(dir.path()) {
        Err(error) => error.to_string(),
        Ok(_) => panic!("a checkpoint without its model was accepted"),
    };
    assert!(message.contains("model.bpk"), "{message}");
}

/// The encoder's latent (inference mode) of `arrays`.
fn inference_latent(model: &bevworld_tokenizer::Tokenizer, arrays: &EncoderArrays) -> Vec<f32> {
    model
        .valid()
        .encode(arrays.to_input(&Device::flex()))
        .latent
        .into_data()
        .try_to_vec::<f32>()
        .expect("latent")
}

#[test]
fn an_ablation_model_reads_and_renders_only_its_modality() {
    let (config, full) = configs();
    let (first, second) = (&frames()[0].encoder, &frames()[1].encoder);
    // The first frame with the second frame's sweep, and with the second frame's images.
    let mut other_sweep = first.clone();
    other_sweep.pillar_slots = second.pillar_slots;
    other_sweep.pillar_points = second.pillar_points.clone();
    other_sweep.pillar_valid = second.pillar_valid.clone();
    other_sweep.pillar_cells = second.pillar_cells.clone();
    let mut other_images = first.clone();
    other_images.images = second.images.clone();

    for (modalities, renders_camera) in [
        (vec![Modality::Camera], true),
        (vec![Modality::Lidar], false),
    ] {
        let mut model = full.clone();
        model.modalities = modalities.clone();
        let mut trainer = trainer(config.clone(), model, frames().clone());
        let report = trainer.train_step().expect("step");
        assert_eq!(
            report.term(Term::Rgb).is_some(),
            renders_camera,
            "{modalities:?}"
        );
        // The committed config weighs the squared RGB term: only a camera model has it.
        assert_eq!(
            report.term(Term::RgbSquared).is_some(),
            renders_camera,
            "{modalities:?}"
        );
        assert_eq!(
            report.term(Term::Lidar).is_some(),
            !renders_camera,
            "{modalities:?}"
        );
        // The distortion term lives on the LiDAR rays: only the LiDAR model has it.
        assert_eq!(
            report.term(Term::Distortion).is_some(),
            !renders_camera,
            "{modalities:?}"
        );
        let w = &trainer.config.loss;
        let expected = report.term(Term::Rgb).map_or(0.0, |l| w.rgb_l1 * l)
            + report.term(Term::RgbSquared).map_or(0.0, |l| w.rgb_l2 * l)
            + report.term(Term::Lidar).map_or(0.0, |l| w.lidar_l1 * l)
            + report
                .term(Term::Distortion)
                .map_or(0.0, |l| w.lidar_distortion * l);
        assert!(
            (report.loss - expected).abs() < 1e-5,
            "{} vs {expected}",
            report.loss
        );
        let v = trainer.validate().expect("validation");
        assert_eq!(v.psnr_db.is_some(), renders_camera);
        assert_eq!(v.chamfer_m2.is_some(), !renders_camera);

        // The encoder ignores the other sensor entirely: swapping it changes nothing, while
        // swapping its own sensor does.
        let latent = inference_latent(trainer.model(), first);
        let (ignored, read) = if renders_camera {
            (&other_sweep, &other_images)
        } else {
            (&other_images, &other_sweep)
        };
        assert!(
            latent == inference_latent(trainer.model(), ignored),
            "{modalities:?} reads the other sensor"
        );
        assert!(
            latent != inference_latent(trainer.model(), read),
            "{modalities:?} ignores its own sensor"
        );
    }
}

#[test]
fn lidar_draw_parses_as_the_config_spells_it() {
    use bevworld_tokenizer_train::LidarDraw;
    for draw in [LidarDraw::Uniform, LidarDraw::ByRange] {
        let spelled = serde_json::to_value(draw).expect("serialises");
        let text = spelled.as_str().expect("a string");
        assert_eq!(text.parse::<LidarDraw>(), Ok(draw), "{text}");
    }
    assert_eq!(
        "nearest".parse::<LidarDraw>().map_err(|e| e.to_string()),
        Err("'nearest' is neither 'uniform' nor 'by_range'".to_string())
    );
}

#[test]
fn with_escape_at_far_training_draws_only_returns_inside_the_voxel_box() {
    let (_dir, data) = small_scene(78, 0.5);
    let (_, tiny) = configs();
    // A far plane of 100 m reaches every return of the synthetic LiDAR, and some lie beyond
    // the voxel box's ±80 m.
    let reaching = TokenizerConfig {
        render: bevworld_tokenizer::config::RenderConfig {
            far: 100.0,
            ..tiny.render.clone()
        },
        ..tiny.clone()
    };
    let escaping = TokenizerConfig {
        render: bevworld_tokenizer::config::RenderConfig {
            escape_at_far: true,
            ..reaching.render.clone()
        },
        ..reaching.clone()
    };
    let load = |model: &TokenizerConfig| {
        load_frames(&data, &FrameInputs::new(model), 1, |_, _| {})
            .expect("frames")
            .remove(0)
    };
    let (plain, boxed) = (load(&reaching), load(&escaping));
    let bev = &tiny.bev;
    let in_box = |frame: &TrainingFrame, i: usize| {
        let (o, d, r) = (
            frame.lidar.origins[i],
            frame.lidar.directions[i],
            frame.lidar_ranges[i],
        );
        [bev.x_range, bev.y_range, bev.z_range]
            .iter()
            .enumerate()
            .all(|(axis, range)| (range[0]..range[1]).contains(&f64::from(o[axis] + r * d[axis])))
    };
    let outside = (0..plain.lidar.len())
        .filter(|&i| !in_box(&plain, i))
        .count();
    assert!(outside > 0, "no return outside the box");
    assert_eq!(boxed.lidar.len(), plain.lidar.len() - outside);
    assert!((0..boxed.lidar.len()).all(|i| in_box(&boxed, i)));
    // Validation and the graph still render every ray of the sweep.
    assert_eq!(boxed.rays.lidar.len(), plain.rays.lidar.len());
}

#[test]
fn a_run_with_a_weight_average_ships_and_validates_it() {
    let (mut config, model) = configs();
    config.ema_decay = Some(0.5);
    config.rays.lidar_rays = 256;
    config.rays.cameras_per_step = 2;
    config.optimizer.warmup_steps = 0;
    let mut run = trainer(config.clone(), model.clone(), frames().clone());
    for _ in 0..2 {
        run.train_step().expect("step");
    }
    let average = module_values(run.weight_average().expect("kept"));
    let iterate = module_values(run.model());
    assert_eq!(average.len(), iterate.len());
    assert!(average != iterate, "the average is the last iterate");
    // The shipped file holds the average, and validation scores it.
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("tokenizer.bpk");
    run.save_weights(&path).expect("weights");
    let shipped = bevworld_tokenizer::load_weights(&model, &path, &Device::flex()).expect("load");
    assert_eq!(module_values(&shipped), average);
    let (scored, iterate_scored) = (
        run.validate().expect("validation"),
        run.validate_iterate()
            .expect("validation")
            .expect("an average is kept"),
    );
    assert_ne!(scored, iterate_scored);

    // A checkpoint without the average cannot resume a run that keeps one.
    let saved = run.save_checkpoint(dir.path()).expect("checkpoint");
    std::fs::remove_file(saved.join("ema.bpk")).expect("the checkpoint holds the average");
    let message = match trainer(config.clone(), model.clone(), frames().clone()).resume(dir.path())
    {
        Err(error) => error.to_string(),
        Ok(_) => panic!("a checkpoint without its weight average was accepted"),
    };
    assert!(message.contains("ema.bpk"), "{message}");

    // Without `ema_decay` the last iterate is shipped and scored once.
    config.ema_decay = None;
    let plain = trainer(config, model, frames().clone());
    assert!(
        plain.weight_average().is_none() && plain.validate_iterate().expect("validation").is_none()
    );
}

#[test]
fn a_validation_frame_that_fails_fails_the_validation_with_any_thread_count() {
    let (config, model) = configs();
    let mut broken = frames()[1].clone();
    // Half an image: building the encoder's input panics on the worker that takes the frame.
    broken
        .encoder
        .images
        .truncate(broken.encoder.images.len() / 2);
    let val = vec![frames()[0].clone(), broken];
    for threads in [1, 2] {
        let run = Trainer::new(
            config.clone(),
            model.clone(),
            &Device::flex(),
            frames().clone(),
            val.clone(),
        )
        .expect("trainer")
        .with_threads(threads);
        match run.validate() {
            Err(TrainError::ValidationWorker { source }) => {
                assert_eq!(source.item, 1, "{threads} threads");
            }
            other => panic!("{threads} threads: a failed validation read {other:?}"),
        }
    }
}

#[test]
fn the_sparsity_prior_is_the_normalised_cauchy_of_alpha_by_hand() {
    use bevworld_tokenizer_train::sparsity::{cauchy_of_alpha, empty_alpha};
    // ε is what skipping calls empty.
    assert_eq!(empty_alpha(), 1e-3);
    // α = 0, ε, 1: ln 1, ln 2 and ln(1 + 1/ε), over 3 · ln(1 + 1/ε):
    // (0 + 0.693147 + 6.908755) / (3 · 6.908755) = 0.366777.
    let alpha = Tensor::<1>::from_floats([0.0, 1e-3, 1.0], &Device::flex());
    let prior: f32 = cauchy_of_alpha(alpha, 1e-3).into_scalar();
    assert!((prior - 0.366777).abs() < 1e-5, "{prior}");
    // Empty everywhere: 0; opaque everywhere: 1.
    for (alpha, expected) in [(0.0, 0.0), (1.0, 1.0)] {
        let all = Tensor::<1>::from_floats([alpha; 4], &Device::flex());
        let prior: f32 = cauchy_of_alpha(all, 1e-3).into_scalar();
        assert!((prior - expected).abs() < 1e-6, "{alpha}: {prior}");
    }
}

#[test]
fn the_sparsity_term_joins_the_loss_only_when_weighted() {
    let (without, with) = steps_without_and_with(|c, w| c.loss.density_sparsity = w, 0.01);
    assert_eq!(without.term(Term::Sparsity), None);
    let term = with.term(Term::Sparsity).expect("sparsity term");
    // An untrained field has α near 0.5 everywhere: ln(1 + 500) / ln(1001) = 0.90.
    assert!(term > 0.8 && term < 1.0, "{term}");
    assert_terms_unchanged(&without, &with);
    assert_total_grows_by(&without, &with, 0.01 * term);
}

/// The encoder's parameters of a tokenizer (every float of the modules that make the latent),
/// and the decoder's, from the module's record by name.
fn encoder_and_decoder_values(model: &bevworld_tokenizer::Tokenizer) -> (Vec<f32>, Vec<f32>) {
    use burn::module::ModuleVisitor;
    struct Split {
        path: Vec<String>,
        encoder: Vec<f32>,
        decoder: Vec<f32>,
    }
    impl ModuleVisitor for Split {
        fn enter_module(&mut self, name: &str, _: &str) {
            self.path.push(name.to_string());
        }
        fn exit_module(&mut self, _: &str, _: &str) {
            self.path.pop();
        }
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let data = param.val().into_data().try_to_vec::<f32>().expect("f32");
            let top = self.path.first().map(String::as_str).unwrap_or("");
            let encoder = [
                "image_backbone",
                "pillar_net",
                "lidar_backbone",
                "fusion",
                "compress",
            ];
            if encoder.contains(&top) {
                self.encoder.extend(data);
            } else {
                self.decoder.extend(data);
            }
        }
    }
    let mut split = Split {
        path: Vec::new(),
        encoder: Vec::new(),
        decoder: Vec::new(),
    };
    model.valid().visit(&mut split);
    (split.encoder, split.decoder)
}

#[test]
fn a_decoder_fine_tune_keeps_the_encoder_and_every_latent_bit_for_bit() {
    let (mut config, model) = configs();
    config.rays.lidar_rays = 256;
    config.rays.cameras_per_step = 2;
    config.loss.density_sparsity = 0.01;
    // Weights to start from: one step of a whole run, so that they are not the seed's.
    let mut first = trainer(config.clone(), model.clone(), frames().clone());
    first.train_step().expect("step");
    let dir = tempfile::tempdir().expect("tempdir");
    let weights = dir.path().join("tokenizer.bpk");
    first.save_weights(&weights).expect("weights");
    let start = bevworld_tokenizer::load_weights(&model, &weights, &Device::flex()).expect("load");
    let (encoder, decoder) = encoder_and_decoder_values(&start);
    assert!(!encoder.is_empty() && !decoder.is_empty());

    config.init = Some(weights.clone());
    config.trains = bevworld_tokenizer_train::TrainedParts::Decoder;
    let mut tuned = trainer(config.clone(), model.clone(), frames().clone())
        .start_from(&weights)
        .expect("the weights load");
    let latent = training_latent(&tuned, &frames()[0]);
    for _ in 0..3 {
        tuned.train_step().expect("step");
    }
    // The iterate and the shipped average: the encoder as it was, to the bit; the decoder moved.
    for (what, model) in [
        ("iterate", tuned.model().valid()),
        ("average", tuned.shipped_model()),
    ] {
        let (now_encoder, now_decoder) = encoder_and_decoder_values(&model);
        assert!(now_encoder == encoder, "the {what}'s encoder changed");
        assert!(now_decoder != decoder, "the {what}'s decoder did not train");
    }
    assert_eq!(training_latent(&tuned, &frames()[0]), latent);

    // A checkpoint resumed keeps it fixed too.
    let run = dir.path().join("run");
    tuned.save_checkpoint(&run).expect("checkpoint");
    let mut resumed = trainer(config, model, frames().clone())
        .resume(&run)
        .expect("resume");
    resumed.train_step().expect("step");
    assert!(encoder_and_decoder_values(&resumed.shipped_model()).0 == encoder);
}
