//! The detector's training on the shared machinery: a step does not depend on how its batch
//! is split over threads, a resumed run continues bit for bit, and steps lower the loss.

use bevworld_heads::{InputKind, InputSpec};
use bevworld_heads_train::{DetectionSet, DetectorTrainer, load_set};
use bevworld_training::Trainee;
use burn::prelude::*;

use crate::data::{config, export, synthetic_set, train_config};

/// The synthetic set and its hand-written export, read once per test.
fn set(dir: &std::path::Path) -> DetectionSet {
    let data = dir.join("set");
    synthetic_set(&data);
    let features = dir.join("features");
    // The maps say nothing of the agents: the loss still falls as the heads learn where and
    // how big agents tend to be, which is enough to exercise the machinery.
    export(&data, &features, |_, _| {});
    load_set(&features, &data, &config()).expect("loads")
}

fn trainer(dir: &std::path::Path, set: &DetectionSet, threads: usize) -> DetectorTrainer {
    let (mean, std) = set.channel_statistics();
    let input = InputSpec {
        kind: InputKind::Latent,
        channels: set.channels,
        grid: set.grid,
        frames: 2,
        model: set.model.clone(),
        weights_hash: set.weights_hash.clone(),
        mean,
        std,
    };
    DetectorTrainer::new(
        train_config(dir, 4, 2),
        config(),
        input,
        set.clone(),
        set.clone(),
        &Device::flex().autodiff(),
        threads,
    )
    .expect("a trainer")
}

fn parameters(trainer: &DetectorTrainer) -> Vec<f32> {
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
fn a_step_splits_over_threads_and_a_resumed_run_continues_bit_for_bit() {
    let dir = tempfile::tempdir().expect("dir");
    let set = set(dir.path());
    let mut one = trainer(dir.path(), &set, 1);
    let mut two = trainer(dir.path(), &set, 2);
    for _ in 0..4 {
        let (a, b) = (
            one.train_step().expect("one"),
            two.train_step().expect("two"),
        );
        assert_eq!(a.loss.to_bits(), b.loss.to_bits());
    }
    let straight = parameters(&one);
    assert_eq!(straight, parameters(&two));

    let run = dir.path().join("run");
    let mut first = trainer(dir.path(), &set, 2);
    for _ in 0..2 {
        first.train_step().expect("step");
    }
    first.save_checkpoint(&run).expect("checkpoint");
    drop(first);
    let mut resumed = trainer(dir.path(), &set, 2).resume(&run).expect("resume");
    assert_eq!(resumed.step(), 2);
    for _ in 0..2 {
        resumed.train_step().expect("step");
    }
    assert_eq!(straight, parameters(&resumed));
}

#[test]
fn steps_lower_the_loss_and_validation_scores_every_keyframe() {
    let dir = tempfile::tempdir().expect("dir");
    let set = set(dir.path());
    let mut trainer = trainer(dir.path(), &set, 2);
    let losses: Vec<f64> = (0..30)
        .map(|_| trainer.train_step().expect("step").loss)
        .collect();
    let first: f64 = losses[..5].iter().sum::<f64>() / 5.0;
    let last: f64 = losses[25..].iter().sum::<f64>() / 5.0;
    // The maps carry nothing of the agents, so the loss falls only as far as priors take it.
    assert!(last < 0.8 * first, "loss {first:.4} -> {last:.4}");
    let validation = trainer.validate().expect("validates");
    assert_eq!(validation[0].frames, set.frames.len());
    let nds = validation[0].score("nds").expect("NDS");
    assert!((0.0..=1.0).contains(&nds), "{nds}");
}
