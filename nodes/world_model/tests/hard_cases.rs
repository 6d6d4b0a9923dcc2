//! The world model's hard cases, each against a known answer or an invariant:
//!
//! - the sampler at its edges: DDIM from t = T under zero terminal SNR, with 1, 50 and 1000
//!   steps, on a scalar example whose answer is known in closed form;
//! - actions outside the training range (1 rad/s, 30 m/s, reversing, standing still): finite
//!   forecasts, each flagged;
//! - an all-zero latent as the whole context;
//! - the forward pass on `wgpu` (a software adapter without a GPU) against `flex`.
//!
//! The long autoregressive rollout and the node's count of flagged forecasts run with the
//! shipped weights, in the workspace's `tests/hard_cases.rs`.

use bevworld_blocks::init::random_normal;
use bevworld_blocks::seeded_init;
use bevworld_types::manoeuvre::constant_turn;
use bevworld_types::{EgoAction, LatentStats};
use bevworld_world_model::config::{DiffusionConfig, ScheduleKind, Target};
use bevworld_world_model::ddim::{clean_and_noise, step, timesteps};
use bevworld_world_model::{
    ActionStats, DdimConfig, NoiseSchedule, Rollout, Spacing, WorldModel, WorldModelConfig,
};
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

fn diffusion(zero_terminal_snr: bool, target: Target) -> DiffusionConfig {
    DiffusionConfig {
        steps: 1000,
        schedule: ScheduleKind::Linear,
        beta_start: 0.00085,
        beta_end: 0.012,
        zero_terminal_snr,
        target,
    }
}

/// The exact network output for data that is one point `c`: the posterior of x₀ given any
/// x_t is `c` itself, so ε = (x_t − √ᾱ c) / √(1 − ᾱ), v = √ᾱ ε − √(1 − ᾱ) c, x₀ = c. With
/// these, deterministic DDIM lands on `c` from any start in any number of steps.
fn exact_output(schedule: &NoiseSchedule, target: Target, x: f64, c: f64, level: usize) -> f64 {
    let a = schedule.alpha_bar(level);
    let (signal, sigma) = (a.sqrt(), (1.0 - a).sqrt());
    let epsilon = (x - signal * c) / sigma;
    match target {
        Target::Epsilon => epsilon,
        Target::V => signal * epsilon - sigma * c,
        Target::X0 => c,
    }
}

#[test]
fn ddim_lands_on_the_closed_form_from_t_equal_t_in_1_50_and_1000_steps() {
    let c = 0.7;
    let start = 1.3; // the initial noise
    for (zero_snr, target) in [
        (true, Target::V),
        (true, Target::X0),
        (false, Target::Epsilon),
        (false, Target::V),
    ] {
        let schedule = NoiseSchedule::new(&diffusion(zero_snr, target));
        if zero_snr {
            assert_eq!(schedule.alpha_bar(1000), 0.0, "pure noise at t = T");
        }
        for steps in [1, 50, 1000] {
            let plan = timesteps(1000, steps, Spacing::Trailing);
            assert_eq!(plan.len(), steps);
            assert_eq!(plan[0].0, 1000, "trailing spacing starts at T");
            let mut x = Tensor::<1>::from_floats([start as f32], &device());
            for &(level, previous) in &plan {
                let now = f64::from(values(x.clone())[0]);
                let output = Tensor::<1>::from_floats(
                    [exact_output(&schedule, target, now, c, level) as f32],
                    &device(),
                );
                let (clean, noise) = clean_and_noise(&schedule, target, x, output, level);
                x = step(&schedule, clean, noise, level, previous, 0.0, None);
                let value = values(x.clone())[0];
                assert!(value.is_finite(), "{target:?}, {steps} steps: step {level}");
            }
            let landed = values(x)[0];
            assert!(
                (f64::from(landed) - c).abs() < 1e-4,
                "{target:?} (zero SNR {zero_snr}), {steps} steps: {landed} against {c}"
            );
        }
    }
    // ε cannot start from pure noise: the config says so instead of dividing by √ᾱ_T = 0.
    let mut config = WorldModelConfig::from_yaml_file(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/models/world-model-tiny.yaml"),
    )
    .expect("tiny");
    config.diffusion = diffusion(true, Target::Epsilon);
    let problems: Vec<String> = config.problems().iter().map(|p| p.to_string()).collect();
    assert!(
        problems.iter().any(|p| p.contains("diffusion.target")),
        "{problems:?}"
    );
}

/// The tiny config made small, with weights that are no longer adaLN-Zero's identity.
fn small_model(seed: u64) -> (WorldModelConfig, WorldModel) {
    use burn::module::{Module, ModuleMapper, Param};
    let mut c = WorldModelConfig::from_yaml_file(
        &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../configs/models/world-model-tiny.yaml"),
    )
    .expect("tiny");
    c.latent_size = [16, 16];
    c.width = 32;
    c.heads = 2;
    c.depth = 2;
    c.condition_half = 16;
    c.x_range = [-20.0, 20.0];
    c.y_range = [-20.0, 20.0];
    struct Perturb(u64);
    impl ModuleMapper for Perturb {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            self.0 += 1;
            let seed = self.0;
            param.map(|t| t.clone() + random_normal(seed, t.dims(), 0.0, 0.05, &t.device()))
        }
    }
    let model = seeded_init(seed, &device(), |d| c.init(d)).map(&mut Perturb(seed));
    (c, model)
}

/// Half a second at a constant speed and yaw rate.
fn action(speed: f64, yaw_rate: f64) -> EgoAction {
    constant_turn(speed, yaw_rate, 0.5)
}

/// Action statistics of ordinary driving: 4 to 12 m/s, gentle turns.
fn driving_stats() -> ActionStats {
    let actions: Vec<EgoAction> = (0..40)
        .map(|i| action(4.0 + 0.2 * i as f64, 0.01 * (i % 7) as f64 - 0.03))
        .collect();
    ActionStats::compute(&actions).expect("stats")
}

/// The small model with ordinary driving's action statistics and plain latent statistics.
struct SmallRollout {
    config: WorldModelConfig,
    model: WorldModel,
    action_stats: ActionStats,
    latent_stats: LatentStats,
}

impl SmallRollout {
    fn new(seed: u64) -> Self {
        let (config, model) = small_model(seed);
        let latent_stats = LatentStats {
            mean: vec![0.1; config.latent_channels],
            std: vec![0.8; config.latent_channels],
            frames: 10,
        };
        Self {
            config,
            model,
            action_stats: driving_stats(),
            latent_stats,
        }
    }

    fn rollout(&self) -> Rollout<'_> {
        Rollout {
            model: &self.model,
            config: &self.config,
            action_stats: &self.action_stats,
            latent_stats: &self.latent_stats,
            device: device(),
        }
    }
}

#[test]
fn actions_outside_the_training_range_give_finite_forecasts_and_are_flagged() {
    let small = SmallRollout::new(3);
    let (c, stats) = (&small.config, &small.action_stats);
    let rollout = small.rollout();
    let [h, w] = c.latent_size;
    let cells = c.latent_channels * h * w;
    let context: Vec<Vec<f32>> = (0..c.context_frames)
        .map(|k| values(random_normal(40 + k as u64, [cells], 0.1, 0.8, &device())))
        .collect();
    let past = vec![action(8.0, 0.0); c.context_frames];
    let sampler = DdimConfig::deterministic(2, 1);
    assert!(!stats.outside_training(&action(8.0, 0.0)));
    for (name, future) in [
        ("1 rad/s", action(8.0, 1.0)),
        ("30 m/s", action(30.0, 0.0)),
        ("reversing", action(-3.0, 0.0)),
        ("standing still", action(0.0, 0.0)),
    ] {
        assert!(stats.outside_training(&future), "{name} is not flagged");
        let output = rollout
            .run(&context, &past, &vec![future; c.future_frames], &sampler)
            .expect(name);
        assert_eq!(output.future.len(), c.future_frames);
        for frame in output.future.iter().chain(&output.ego_warped) {
            assert_eq!(frame.len(), cells);
            assert!(frame.iter().all(|v| v.is_finite()), "{name}");
        }
    }
}

#[test]
fn an_all_zero_context_gives_a_finite_forecast() {
    let small = SmallRollout::new(4);
    let (c, latents) = (&small.config, &small.latent_stats);
    let rollout = small.rollout();
    let [h, w] = c.latent_size;
    let cells = c.latent_channels * h * w;
    let zeros = vec![vec![0.0f32; cells]; c.context_frames];
    let output = rollout
        .run(
            &zeros,
            &vec![action(8.0, 0.0); c.context_frames],
            &vec![action(8.0, 0.0); c.future_frames],
            &DdimConfig::deterministic(4, 2),
        )
        .expect("zeros");
    // The ego-warped zero latent is zero where it comes from inside the grid, and the
    // statistics' mean (a standardised 0) where it comes from outside; and the forecast is
    // finite.
    let mean = latents.mean[0] as f32;
    for frame in &output.ego_warped {
        assert!(
            frame
                .iter()
                .all(|v| v.abs() < 1e-6 || (v - mean).abs() < 1e-6 || (*v > 0.0 && *v < mean)),
            "a warped zero latent holds only 0, the mean, and blends of them at the border"
        );
    }
    for frame in &output.future {
        assert!(frame.iter().all(|v| v.is_finite()));
    }
}

/// Tolerance of `wgpu` against `flex`: 1e-4 absolute on outputs of order 1, as for the
/// tokenizer (`nodes/tokenizer/tests/backends.rs`): f32 on both, summed in other orders.
const BACKEND_TOLERANCE: f32 = 1e-4;

#[test]
fn flex_and_wgpu_agree_on_the_world_model() {
    use burn::module::Module;
    let (c, model) = small_model(5);
    let frames = c.context_frames + c.future_frames;
    let [h, w] = c.latent_size;
    let latents = values(random_normal(
        60,
        [1, frames, c.latent_channels, h, w],
        0.0,
        1.0,
        &device(),
    ));
    let actions = values(random_normal(61, [1, frames, 5], 0.0, 1.0, &device()));
    let levels: Vec<f32> = (0..frames)
        .map(|f| if f < c.context_frames { 0.0 } else { 500.0 })
        .collect();
    let run = |device: &Device| -> Vec<f32> {
        let model = model.clone().to_device(device);
        let latents = Tensor::<5>::from_data(
            TensorData::new(latents.clone(), [1, frames, c.latent_channels, h, w]),
            device,
        );
        let actions =
            Tensor::<3>::from_data(TensorData::new(actions.clone(), [1, frames, 5]), device);
        values(model.forward(latents, actions, &levels, c.future_frames, None))
    };
    let cpu = run(&Device::flex());
    let gpu = run(&Device::wgpu(DeviceKind::DefaultDevice));
    let worst = cpu
        .iter()
        .zip(&gpu)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    let scale = cpu.iter().map(|v| v.abs()).fold(0.0f32, f32::max);
    println!("world model: max |flex - wgpu| = {worst:e} (max |value| {scale})");
    assert!(scale > 1e-2, "the output carries signal");
    assert!(worst < BACKEND_TOLERANCE, "flex and wgpu differ by {worst}");
}
