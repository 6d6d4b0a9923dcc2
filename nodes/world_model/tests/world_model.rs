//! The world model against the invariants it must hold: shapes at both sizes, causality in
//! time, condition frames the sampler never alters, adaLN-Zero's identity start, seeded and
//! deterministic sampling, refused configs and weights that do not pair.

use std::path::PathBuf;

use bevworld_blocks::init::{random_normal, random_tensor};
use bevworld_blocks::{causal_mask, seeded_init};
use bevworld_world_model::weights::meta_path_for;
use bevworld_world_model::{
    ActionStats, ContextPasses, DdimConfig, ForecastInputs, NoiseSchedule, ResidualShrink, Spacing,
    WeightsMeta, WorldModel, WorldModelConfig, WorldModelWeightsError, forecast, forecast_with,
    load_weights, save_weights,
};
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn config(name: &str) -> WorldModelConfig {
    WorldModelConfig::from_yaml_file(&repo().join(format!("configs/models/{name}.yaml")))
        .expect("config")
}

/// The tiny config made smaller still, for tests that run many forward passes.
fn small() -> WorldModelConfig {
    let mut c = config("world-model-tiny");
    c.latent_size = [16, 16];
    c.width = 32;
    c.heads = 2;
    c.depth = 2;
    c.condition_half = 16;
    c.context_frames = 2;
    c.future_frames = 3;
    c
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

/// A model whose gates and head are no longer zero, so that every path carries signal.
fn trained_like(config: &WorldModelConfig, seed: u64) -> WorldModel {
    use burn::module::{ModuleMapper, Param};
    struct Perturb(u64);
    impl ModuleMapper for Perturb {
        fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
            self.0 += 1;
            let seed = self.0;
            param.map(|t| {
                let noise = random_normal(seed, t.dims(), 0.0, 0.05, &t.device());
                t + noise
            })
        }
    }
    seeded_init(seed, &device(), |d| config.init(d)).map(&mut Perturb(seed))
}

fn inputs(config: &WorldModelConfig, batch: usize, seed: u64) -> (Tensor<5>, Tensor<3>) {
    let frames = config.context_frames + config.future_frames;
    let [h, w] = config.latent_size;
    let latents = random_normal(
        seed,
        [batch, frames, config.latent_channels, h, w],
        0.0,
        1.0,
        &device(),
    );
    let actions = random_normal(seed + 1, [batch, frames, 5], 0.0, 1.0, &device());
    (latents, actions)
}

fn levels(config: &WorldModelConfig, batch: usize, level: f32) -> Vec<f32> {
    (0..batch)
        .flat_map(|_| {
            std::iter::repeat_n(0.0, config.context_frames)
                .chain(std::iter::repeat_n(level, config.future_frames))
        })
        .collect()
}

#[test]
fn the_tiny_model_predicts_its_future_frames_only() {
    let c = config("world-model-tiny");
    assert_eq!(c.token_grid(), [16, 16]);
    let model = seeded_init(0, &device(), |d| c.init(d));
    let (latents, actions) = inputs(&c, 2, 3);
    let out = model.forward(
        latents,
        actions,
        &levels(&c, 2, 500.0),
        c.future_frames,
        None,
    );
    assert_eq!(out.dims(), [2, 6, 4, 64, 64]);
}

#[test]
fn the_paper_model_runs_at_batch_one() {
    // The paper's widths and patch; one block and two frames, since depth and frame count
    // change no shape and the full model costs ~1 TFLOP a pass on a CPU.
    let mut c = config("world-model-paper");
    assert_eq!(c.token_grid(), [48, 48]);
    c.depth = 1;
    c.context_frames = 1;
    c.future_frames = 1;
    let model = seeded_init(0, &device(), |d| c.init(d));
    let (latents, actions) = inputs(&c, 1, 4);
    let out = model.forward(latents, actions, &levels(&c, 1, 10.0), 1, None);
    assert_eq!(out.dims(), [1, 1, 4, 96, 96]);
}

#[test]
fn a_frame_never_changes_the_output_of_an_earlier_frame() {
    let c = small();
    let model = trained_like(&c, 7);
    let (latents, actions) = inputs(&c, 1, 11);
    let frames = c.context_frames + c.future_frames;
    let all = c.future_frames + c.context_frames;
    // Predict every frame, so that condition frames' outputs are checked too.
    let before = model.forward(
        latents.clone(),
        actions.clone(),
        &levels(&c, 1, 300.0),
        all,
        None,
    );
    for k in 1..frames {
        let mut changed = latents.clone();
        let bump = random_tensor(99 + k as u64, [1, 1, 4, 16, 16], -3.0, 3.0, &device());
        changed = changed.clone().slice_assign(
            [0..1, k..k + 1, 0..4, 0..16, 0..16],
            changed.narrow(1, k, 1) + bump,
        );
        let mut changed_actions = actions.clone();
        changed_actions = changed_actions.clone().slice_assign(
            [0..1, k..k + 1, 0..5],
            changed_actions.narrow(1, k, 1).add_scalar(2.0),
        );
        let after = model.forward(changed, changed_actions, &levels(&c, 1, 300.0), all, None);
        let earlier = |t: Tensor<5>| values(t.narrow(1, 0, k));
        assert_eq!(
            earlier(before.clone()),
            earlier(after.clone()),
            "frame {k} leaked backwards"
        );
        let moved: f32 = values((before.clone().narrow(1, k, 1) - after.narrow(1, k, 1)).abs())
            .iter()
            .sum();
        assert!(moved > 1e-3, "frame {k}'s own output ignored its change");
    }
}

#[test]
fn every_block_starts_as_the_identity_and_the_model_at_zero() {
    let c = small();
    let model = seeded_init(3, &device(), |d| c.init(d));
    let x = random_normal(5, [1, 5, 64, c.width], 0.0, 1.0, &device());
    let condition = random_normal(6, [1, 5, 2 * c.condition_half], 0.0, 1.0, &device());
    for block in model.blocks() {
        let out = block.forward(x.clone(), condition.clone(), causal_mask(5, &device()));
        assert_eq!(values(out), values(x.clone()));
    }
    let (latents, actions) = inputs(&c, 1, 8);
    let out = model.forward(
        latents,
        actions,
        &levels(&c, 1, 900.0),
        c.future_frames,
        None,
    );
    assert!(values(out).iter().all(|v| *v == 0.0));
}

fn forecast_inputs(c: &WorldModelConfig, seed: u64) -> ForecastInputs {
    let [h, w] = c.latent_size;
    let context = random_normal(seed, [1, c.context_frames, 4, h, w], 0.0, 1.0, &device());
    let frames = c.context_frames + c.future_frames;
    let actions = random_normal(seed + 1, [1, frames, 5], 0.0, 1.0, &device());
    let base = random_normal(seed + 2, [1, c.future_frames, 4, h, w], 0.0, 1.0, &device());
    ForecastInputs {
        context,
        actions,
        base: Some(base.clone()),
        warped: base,
        fine_tokens: Default::default(),
    }
}

#[test]
fn sampling_is_seeded_and_deterministic_and_leaves_the_context_alone() {
    let c = small();
    let model = trained_like(&c, 9);
    let schedule = NoiseSchedule::new(&c.diffusion);
    let inputs = forecast_inputs(&c, 20);
    let context_before = values(inputs.context.clone());
    let sampler = |seed: u64, eta: f64| DdimConfig {
        steps: 4,
        eta,
        spacing: Spacing::Trailing,
        seed,
        shrink: None,
    };
    let a = values(forecast(&model, &c, &schedule, &inputs, &sampler(1, 0.0)).expect("a"));
    let again = values(forecast(&model, &c, &schedule, &inputs, &sampler(1, 0.0)).expect("b"));
    let other = values(forecast(&model, &c, &schedule, &inputs, &sampler(2, 0.0)).expect("c"));
    assert_eq!(a, again);
    assert!(a.iter().all(|v| v.is_finite()));
    let differ = a.iter().zip(&other).filter(|(x, y)| x != y).count();
    assert!(
        differ > a.len() / 2,
        "seeds 1 and 2 agree on {} of {} values",
        a.len() - differ,
        a.len()
    );
    // η > 0 adds seeded noise: still deterministic for a seed.
    let noisy = values(forecast(&model, &c, &schedule, &inputs, &sampler(1, 1.0)).expect("d"));
    assert_eq!(
        noisy,
        values(forecast(&model, &c, &schedule, &inputs, &sampler(1, 1.0)).expect("e"))
    );
    assert_ne!(noisy, a);
    assert_eq!(values(inputs.context.clone()), context_before);
    // One step, the paper's usual 50, and every one of the T = 1000 levels, from pure noise
    // under zero terminal SNR: each stays finite (the small model's 1000 passes take seconds).
    for steps in [1, 50, 1000] {
        let sampler = DdimConfig::deterministic(steps, 3);
        let out = values(forecast(&model, &c, &schedule, &inputs, &sampler).expect("forecast"));
        assert!(
            out.iter().all(|v| v.is_finite()),
            "{steps} steps gave a non-finite latent"
        );
    }
    let bad = DdimConfig::deterministic(0, 0);
    assert!(forecast(&model, &c, &schedule, &inputs, &bad).is_err());
    let bad = DdimConfig { steps: 1001, ..bad };
    let error = forecast(&model, &c, &schedule, &inputs, &bad).expect_err("refused");
    assert!(
        error.to_string().contains("1001") && error.to_string().contains("1000"),
        "{error}"
    );
}

#[test]
fn the_shrink_keeps_the_warp_where_the_residual_is_small_and_leaves_its_last_horizon_alone() {
    let c = small(); // 3 future frames 0.5 s apart
    let model = trained_like(&c, 9);
    let schedule = NoiseSchedule::new(&c.diffusion);
    let inputs = forecast_inputs(&c, 20);
    let base = inputs.base.clone().expect("a residual model's inputs");
    let plain = DdimConfig::deterministic(1, 4);
    let shrink = ResidualShrink {
        tau: 0.3,
        fade_s: 1.5,
    };
    let shrunk = DdimConfig {
        shrink: Some(shrink),
        ..plain.clone()
    };
    let residual = |sampler: &DdimConfig| -> Vec<Vec<f32>> {
        let out = forecast(&model, &c, &schedule, &inputs, sampler).expect("forecast");
        let r = values(out - base.clone());
        r.chunks(r.len() / c.future_frames)
            .map(<[f32]>::to_vec)
            .collect()
    };
    let (raw, kept) = (residual(&plain), residual(&shrunk));
    for (k, (raw, kept)) in raw.iter().zip(&kept).enumerate() {
        let tau = shrink.tau_at((k + 1) as f64 * c.frame_interval_s) as f32;
        let mut zeroed = 0;
        for (r, s) in raw.iter().zip(kept) {
            // r' = sign(r)·max(|r| − τ, 0), up to the rounding of (r + base) − base.
            let want = r.signum() * (r.abs() - tau).max(0.0);
            assert!(
                (s - want).abs() < 1e-5,
                "frame {k}: {r} -> {s}, want {want}"
            );
            zeroed += usize::from(r.abs() < tau);
        }
        if k + 1 == c.future_frames {
            assert_eq!(tau, 0.0);
            assert_eq!(raw, kept, "the last horizon is at fade_s: untouched");
        } else {
            assert!(zeroed > 0, "frame {k}: no residual under τ = {tau}");
        }
    }
}

#[test]
fn configs_that_cannot_work_are_refused_naming_the_field() {
    let text =
        std::fs::read_to_string(repo().join("configs/models/world-model-tiny.yaml")).expect("read");
    let unknown = format!("{text}\nescape_at_fra: true\n");
    let error = WorldModelConfig::from_yaml(&unknown, "wm.yaml").expect_err("unknown key");
    assert!(error.to_string().contains("escape_at_fra"), "{error}");
    let epsilon = text.replace("target: v", "target: epsilon");
    let error = WorldModelConfig::from_yaml(&epsilon, "wm.yaml").expect_err("epsilon at zero SNR");
    assert!(error.to_string().contains("diffusion.target"), "{error}");
    let odd = text.replace("patch: 4", "patch: 3");
    let error = WorldModelConfig::from_yaml(&odd, "wm.yaml").expect_err("patch");
    assert!(
        error.to_string().contains("latent_size") && error.to_string().contains("wm.yaml"),
        "{error}"
    );
    let fade_without_residual = text.replace(
        "residual_over_ego_warp: true",
        "residual_over_ego_warp: false\nego_warp_fade_s: 3.0",
    );
    let error = WorldModelConfig::from_yaml(&fade_without_residual, "wm.yaml")
        .expect_err("a fade with nothing to fade");
    assert!(error.to_string().contains("ego_warp_fade_s"), "{error}");
    let heads = text.replace("heads: 4", "heads: 3");
    assert!(
        WorldModelConfig::from_yaml(&heads, "wm.yaml")
            .expect_err("heads")
            .to_string()
            .contains("heads")
    );
}

fn meta(c: &WorldModelConfig) -> WeightsMeta {
    WeightsMeta {
        model: c.name.clone(),
        tokenizer_model: "tokenizer-tiny".into(),
        tokenizer_weights_hash: "00000000deadbeef".into(),
        action_stats: ActionStats {
            mean: [8.0, 0.0, 4.0, 0.0, 0.0],
            std: [2.0, 0.2, 1.0, 0.1, 0.1],
            count: 10,
            range: None,
        },
        steps: 1,
        command: "test".into(),
    }
}

#[test]
fn weights_load_only_with_their_config_and_their_tokenizer() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("wm.bpk");
    let c = small();
    let model = trained_like(&c, 4);
    save_weights(&model, &meta(&c), &path).expect("save");
    let loaded = load_weights(
        &c,
        &path,
        Some(("tokenizer-tiny", "00000000deadbeef")),
        &device(),
    )
    .expect("load");
    assert_eq!(loaded.meta, meta(&c));
    // The seal holds for statistics whose printed digits serde_json reads back one unit in the
    // last place off (the shipped mean's 3.6262073335357203): what is sealed is what a reader
    // gets.
    let mut awkward = meta(&c);
    awkward.action_stats.mean[2] = 3.6262073335357203;
    awkward.action_stats.range = Some(bevworld_world_model::actions::ActionRange {
        min: [1.6156046390533447, -0.9463784694671631, 0.8, -0.8, -0.4],
        max: [12.9, 0.7, 6.5, 0.6, 0.4],
    });
    let awkward_path = dir.path().join("awkward.bpk");
    save_weights(&model, &awkward, &awkward_path).expect("save");
    let reread = load_weights(&c, &awkward_path, None, &device()).expect("sealed as read back");
    for k in 0..5 {
        assert!((reread.meta.action_stats.mean[k] - awkward.action_stats.mean[k]).abs() < 1e-12);
    }
    let (latents, actions) = inputs(&c, 1, 2);
    let lv = levels(&c, 1, 40.0);
    assert_eq!(
        values(
            loaded
                .model
                .forward(latents.clone(), actions.clone(), &lv, 3, None)
        ),
        values(model.forward(latents, actions, &lv, 3, None))
    );
    match load_weights(
        &c,
        &path,
        Some(("tokenizer-tiny", "1111111111111111")),
        &device(),
    ) {
        Err(error @ WorldModelWeightsError::Tokenizer { .. }) => {
            let text = error.to_string();
            assert!(
                text.contains("00000000deadbeef") && text.contains("1111111111111111"),
                "{text}"
            );
        }
        other => panic!("expected a tokenizer mismatch, got {:?}", other.err()),
    }
    let mut wider = c.clone();
    wider.width = 64;
    let error = load_weights(&wider, &path, None, &device())
        .err()
        .expect("wider refused");
    assert!(error.to_string().contains("do not fit"), "{error}");
    std::fs::remove_file(meta_path_for(&path)).expect("remove meta");
    let error = load_weights(&c, &path, None, &device())
        .err()
        .expect("no meta");
    assert!(error.to_string().contains("wm.meta.json"), "{error}");
}

#[test]
fn the_context_cache_changes_no_prediction_and_no_forecast() {
    let mut c = small();
    c.ego_warp_input = true;
    let model = trained_like(&c, 12);
    let (latents, actions) = inputs(&c, 2, 30);
    let (p, n) = (c.context_frames, c.future_frames);
    let [h, w] = c.latent_size;
    let warped = random_normal(31, [2, n, 4, h, w], 0.0, 1.0, &device());
    let level = 400.0;
    let whole = model.forward(
        latents.clone(),
        actions.clone(),
        &levels(&c, 2, level),
        n,
        Some(warped.clone()),
    );
    let without_warp = model.forward(
        latents.clone(),
        actions.clone(),
        &levels(&c, 2, level),
        n,
        None,
    );
    assert!(
        values((whole.clone() - without_warp).abs())
            .into_iter()
            .fold(0.0, f32::max)
            > 1e-3,
        "the warp the future frames embed changes their prediction"
    );
    let cache = model.context(
        latents.clone().narrow(1, 0, p),
        actions.clone().narrow(1, 0, p),
    );
    assert_eq!(cache.frames(), p);
    let cached = model.forward_future(
        &cache,
        latents.narrow(1, p, n),
        actions.narrow(1, p, n),
        &vec![level; 2 * n],
        Some(warped),
    );
    let gap = values((whole.clone() - cached).abs())
        .into_iter()
        .fold(0.0, f32::max);
    let scale = values(whole.abs()).into_iter().fold(0.0, f32::max);
    assert!(scale > 1e-2, "the prediction carries signal ({scale})");
    assert!(
        gap <= 1e-5 * scale.max(1.0),
        "cached and whole differ by {gap}"
    );

    let schedule = NoiseSchedule::new(&c.diffusion);
    let inputs = forecast_inputs(&c, 40);
    for steps in [1, 3, 8] {
        let sampler = DdimConfig::deterministic(steps, 5);
        let run = |passes: ContextPasses| {
            values(
                forecast_with(&model, &c, &schedule, &inputs, &sampler, passes).expect("forecast"),
            )
        };
        let (a, b) = (run(ContextPasses::Cached), run(ContextPasses::EveryStep));
        let gap = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(
            gap <= 1e-4,
            "{steps} steps: cached and recomputed differ by {gap}"
        );
    }
}

#[test]
fn inference_on_the_cpu_equals_the_tensor_path_of_training() {
    // CPU inference runs our host kernels (attention read from the packed projection where it
    // lies, across frames and within them); under autodiff the model runs burn's ops, as in
    // training. Both must predict the same, whole and after the condition frames' cache.
    use burn::module::Module;
    let c = small();
    let model = trained_like(&c, 11);
    let (latents, actions) = inputs(&c, 2, 12);
    let levels = levels(&c, 2, 300.0);
    let autodiff = device().autodiff();
    let taught = model.clone().to_device(&autodiff);
    let to5 = |t: &Tensor<5>| Tensor::<5>::from_data(t.clone().into_data(), &autodiff);
    let to3 = |t: &Tensor<3>| Tensor::<3>::from_data(t.clone().into_data(), &autodiff);
    let whole = model.forward(
        latents.clone(),
        actions.clone(),
        &levels,
        c.future_frames,
        None,
    );
    let whole_taught = taught.forward(to5(&latents), to3(&actions), &levels, c.future_frames, None);
    let gap = largest_gap(&values(whole), &values(whole_taught));
    assert!(gap < 1e-4, "whole: {gap}");

    let p = c.context_frames;
    let future = c.future_frames;
    let split = |t: &Tensor<5>| (t.clone().narrow(1, 0, p), t.clone().narrow(1, p, future));
    let split3 = |t: &Tensor<3>| (t.clone().narrow(1, 0, p), t.clone().narrow(1, p, future));
    let (context, later) = split(&latents);
    let (context_actions, later_actions) = split3(&actions);
    let future_levels: Vec<f32> = levels
        .chunks(p + future)
        .flat_map(|frames| frames[p..].to_vec())
        .collect();
    let cached = model.forward_future(
        &model.context(context.clone(), context_actions.clone()),
        later.clone(),
        later_actions.clone(),
        &future_levels,
        None,
    );
    let cached_taught = taught.forward_future(
        &taught.context(to5(&context), to3(&context_actions)),
        to5(&later),
        to3(&later_actions),
        &future_levels,
        None,
    );
    let gap = largest_gap(&values(cached), &values(cached_taught));
    assert!(gap < 1e-4, "after the cache: {gap}");
}

fn largest_gap(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// `small` with a fine stage: patch 4 on 16 × 16 cells, a 4 × 4 token grid.
fn small_fine() -> WorldModelConfig {
    let mut c = small();
    c.name = "world-model-fine-small".into();
    c.fine_tokens = Some(bevworld_world_model::FineTokensConfig {
        width: 16,
        depth: 1,
        heads: 2,
        select: bevworld_world_model::FineTokenRule {
            threshold: 1.0,
            dilate: 0,
        },
    });
    c
}

fn selection(tokens: Vec<Vec<usize>>) -> bevworld_world_model::FineTokenSelection {
    bevworld_world_model::FineTokenSelection { tokens }
}

#[test]
fn a_fine_stage_starts_as_the_coarse_model_it_extends() {
    // Its head is zero at initialisation: a coarse model's trained weights with a fresh fine
    // stage predict what the coarse model predicts, even with every token opened.
    let coarse = trained_like(&small(), 21);
    let fine_config = small_fine();
    let stage = fine_config
        .fine_stage()
        .expect("a fine stage")
        .init(&device());
    let fine = coarse.clone().with_fine_stage(stage);
    let (latents, actions) = inputs(&fine_config, 2, 22);
    let levels = levels(&fine_config, 2, 500.0);
    let all = selection(vec![(0..16).collect(), (0..16).collect()]);
    let future = fine_config.future_frames;
    let extended = fine.forward_selected(
        latents.clone(),
        actions.clone(),
        &levels,
        future,
        None,
        &all,
    );
    let plain = coarse.forward(latents, actions, &levels, future, None);
    assert_eq!(values(extended), values(plain));
}

#[test]
fn fine_tokens_change_only_the_cells_of_the_selected_tokens() {
    let c = small_fine();
    let model = trained_like(&c, 23);
    let (latents, actions) = inputs(&c, 2, 24);
    let levels = levels(&c, 2, 400.0);
    let future = c.future_frames;
    let run = |tokens: Vec<Vec<usize>>| {
        values(model.forward_selected(
            latents.clone(),
            actions.clone(),
            &levels,
            future,
            None,
            &selection(tokens),
        ))
    };
    let none = run(vec![vec![], vec![]]);
    assert_eq!(
        none,
        values(model.forward(latents.clone(), actions.clone(), &levels, future, None)),
        "no selection is the coarse model"
    );
    // Token 1 of item 0: token row 0, column 1, cells y 0..4, x 4..8 of every frame and
    // channel. Nothing else may move; every one of its cells must.
    let one = run(vec![vec![1], vec![]]);
    let [h, w] = c.latent_size;
    let channels = c.latent_channels;
    for (index, (a, b)) in none.iter().zip(&one).enumerate() {
        let x = index % w;
        let y = (index / w) % h;
        let item = index / (w * h * channels * future);
        let inside = item == 0 && y < 4 && (4..8).contains(&x);
        if inside {
            assert!(
                (a - b).abs() > 1e-7,
                "cell {index} inside the token did not move"
            );
        } else {
            assert_eq!(a, b, "cell {index} outside the token moved");
        }
    }
}

#[test]
fn with_fine_tokens_the_cache_and_the_tensor_path_agree() {
    // The fine stage reads the condition frames from the cache; under autodiff it runs burn's
    // ops. All three must predict the same.
    use burn::module::Module;
    let c = small_fine();
    let model = trained_like(&c, 25);
    let (latents, actions) = inputs(&c, 2, 26);
    let levels = levels(&c, 2, 300.0);
    let chosen = selection(vec![vec![0, 5, 15], vec![6]]);
    let (p, future) = (c.context_frames, c.future_frames);
    let whole = values(model.forward_selected(
        latents.clone(),
        actions.clone(),
        &levels,
        future,
        None,
        &chosen,
    ));
    let future_levels: Vec<f32> = levels
        .chunks(p + future)
        .flat_map(|frames| frames[p..].to_vec())
        .collect();
    let cached = values(model.forward_future_selected(
        &model.context(
            latents.clone().narrow(1, 0, p),
            actions.clone().narrow(1, 0, p),
        ),
        latents.clone().narrow(1, p, future),
        actions.clone().narrow(1, p, future),
        &future_levels,
        None,
        &chosen,
    ));
    assert!(
        largest_gap(&whole, &cached) < 1e-4,
        "cache: {}",
        largest_gap(&whole, &cached)
    );
    let autodiff = device().autodiff();
    let taught = model.to_device(&autodiff);
    let taught_out = values(taught.forward_selected(
        Tensor::<5>::from_data(latents.into_data(), &autodiff),
        Tensor::<3>::from_data(actions.into_data(), &autodiff),
        &levels,
        future,
        None,
        &chosen,
    ));
    assert!(
        largest_gap(&whole, &taught_out) < 1e-4,
        "autodiff: {}",
        largest_gap(&whole, &taught_out)
    );
}
