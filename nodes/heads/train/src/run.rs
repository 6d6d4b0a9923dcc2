//! A whole detector run, as `bevworld train detector` asks for one: the configs, the three
//! sets' exported features and annotations, the standardisation from the training maps, the
//! loop (`bevworld_training::run_loop`), the weights with their metadata and curves, and the
//! one score on the test set, with its detections in the submission format. The command line
//! exports the features through the graph, and prints.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevworld_heads::config::ConfigError;
use bevworld_heads::weights::{DetectorWeightsError, save_detector};
use bevworld_heads::{DetectorConfig, DetectorMeta, InputKind, InputSpec};
use bevworld_training::checkpoint;
use bevworld_training::curves::CurvesError;
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{LoopPlan, MetricsLog, Observer, Trainee, plot_curves, run_loop};
use bevworld_types::{DetectionResults, SubmissionMeta};
use burn::prelude::*;

use crate::config::TrainDetectorConfig;
use crate::data::{DataError, DetectionSet, load_set};
use crate::evaluate::{Evaluation, predict, results_of};
use crate::trainer::{CURVES, DetectorTrainer, TrainError, columns};

/// How the encoder that makes the features starts: `frozen` reads the exported features of the
/// shipped tokenizer, so only the heads learn (what a user of the export gets).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Init {
    Frozen,
}

impl Init {
    pub fn name(self) -> &'static str {
        match self {
            Init::Frozen => "frozen",
        }
    }
}

/// One run, as asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainRequest {
    pub config: PathBuf,
    pub input: InputKind,
    /// 1 or 2.
    pub frames: usize,
    pub init: Init,
    /// The run folder: checkpoints, `metrics.csv`, `curves.png`, `detector.bpk`, `test/`.
    pub out: PathBuf,
    pub resume: bool,
    /// Steps instead of the config's (the schedule follows).
    pub steps: Option<usize>,
    pub threads: Option<usize>,
    pub log_every: usize,
    /// The command line, recorded in the weights' metadata.
    pub command: String,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("{0}")]
    Input(String),
    #[error(
        "{run} already holds checkpoints: pass --resume to continue that run, or choose another --out"
    )]
    Exists { run: PathBuf },
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Weights(#[from] DetectorWeightsError),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
    #[error(transparent)]
    Curves(#[from] CurvesError),
    #[error("{path}: {message}")]
    Write { path: PathBuf, message: String },
}

impl From<checkpoint::CheckpointError> for RunError {
    fn from(error: checkpoint::CheckpointError) -> Self {
        RunError::Train(TrainError::Checkpoint(error))
    }
}

/// What a run did.
pub struct TrainSummary {
    pub steps: usize,
    pub minutes: f64,
    pub weights: PathBuf,
    pub curves: PathBuf,
    pub input: InputSpec,
    pub validation: Option<Evaluation>,
    pub test: Evaluation,
    /// `RUN/test/results_nusc.json` and `RUN/test/scores.json`.
    pub test_results: PathBuf,
    pub test_scores: PathBuf,
}

/// The config as this run trains it.
pub fn effective_config(request: &TrainRequest) -> Result<TrainDetectorConfig, RunError> {
    let mut config = TrainDetectorConfig::from_yaml_file(&request.config)?;
    if let Some(steps) = request.steps {
        config.steps = steps;
    }
    Ok(config)
}

fn same_maker(name: &str, set: &DetectionSet, train: &DetectionSet) -> Result<(), RunError> {
    if set.model != train.model || set.weights_hash != train.weights_hash || set.grid != train.grid
    {
        return Err(RunError::Input(format!(
            "the {name} set's features were made by '{}' with weights {} on {:?}, the training set's by '{}' with weights {} on {:?}: export all three with the same model",
            set.model, set.weights_hash, set.grid, train.model, train.weights_hash, train.grid
        )));
    }
    Ok(())
}

/// Trains on `device` (autodiff is added here); the three sets' features must be exported.
pub fn train(
    request: &TrainRequest,
    device: &Device,
    observer: &mut dyn Observer,
) -> Result<TrainSummary, RunError> {
    let config = effective_config(request)?;
    let detector = DetectorConfig::from_yaml_file(&config.model)?;
    let has_checkpoint = match (checkpoint::latest(&request.out), request.resume) {
        (Err(checkpoint::CheckpointError::None { .. }), _) => false,
        (Ok(_), true) => true,
        (_, false) => {
            return Err(RunError::Exists {
                run: request.out.clone(),
            });
        }
        (Err(error), true) => return Err(error.into()),
    };
    let load = |set: &crate::config::FeatureSet| {
        load_set(&set.folder(request.input), &set.synth.dir, &detector)
    };
    let train_set = load(&config.train)?;
    let val_set = load(&config.val)?;
    let test_set = load(&config.test)?;
    same_maker("validation", &val_set, &train_set)?;
    same_maker("test", &test_set, &train_set)?;
    let (mean, std) = train_set.channel_statistics();
    let input = InputSpec {
        kind: request.input,
        channels: train_set.channels,
        grid: train_set.grid,
        frames: request.frames,
        model: train_set.model.clone(),
        weights_hash: train_set.weights_hash.clone(),
        mean,
        std,
    };
    if let Some(problem) = detector.input_problems(&input).first() {
        return Err(RunError::Input(format!(
            "{}: {problem}",
            config.train.folder(request.input).display()
        )));
    }
    let threads = request
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let autodiff = device.clone().autodiff();
    let mut trainer = DetectorTrainer::new(
        config.clone(),
        detector.clone(),
        input.clone(),
        train_set,
        val_set,
        &autodiff,
        threads,
    )?;
    if has_checkpoint {
        trainer = trainer.resume(&request.out)?;
    }
    let resumed_at = trainer.step();
    std::fs::create_dir_all(&request.out).map_err(|e| RunError::Write {
        path: request.out.clone(),
        message: e.to_string(),
    })?;
    let mut log = MetricsLog::open(
        &request.out,
        &columns(),
        (resumed_at > 0).then_some(resumed_at),
    )?;
    let started = Instant::now();
    let plan = LoopPlan {
        stop: config.steps,
        log_every: request.log_every,
        validate_every: config.validate_every,
        checkpoint_every: config.checkpoint_every,
    };
    run_loop(
        &mut trainer,
        &request.out,
        plan,
        &mut log,
        started,
        observer,
    )?;
    if trainer.last_evaluation().is_none() {
        trainer.validate()?;
    }
    let weights = request.out.join("detector.bpk");
    let meta = DetectorMeta {
        config: detector.clone(),
        input: input.clone(),
        init: request.init.name().to_string(),
        steps: trainer.step(),
        command: request.command.clone(),
        weights_hash: String::new(),
    };
    let model = trainer.shipped_model();
    save_detector(&model, &meta, &weights)?;
    let curves = request.out.join("curves.png");
    plot_curves(log.path(), &curves, &CURVES)?;

    let test = trainer.evaluate(&model, &test_set)?;
    let detections = predict(&model, &detector, &input, &test_set, threads, device)
        .map_err(TrainError::Predict)?;
    let results = DetectionResults {
        meta: SubmissionMeta {
            use_camera: input.kind != InputKind::BevStats,
            use_lidar: true,
            ..Default::default()
        },
        results: results_of(&test_set, &detections),
    };
    let test_dir = request.out.join("test");
    std::fs::create_dir_all(&test_dir).map_err(|e| RunError::Write {
        path: test_dir.clone(),
        message: e.to_string(),
    })?;
    let test_results = test_dir.join("results_nusc.json");
    results.save(&test_results).map_err(|e| RunError::Write {
        path: test_results.clone(),
        message: e.to_string(),
    })?;
    let test_scores = test_dir.join("scores.json");
    write_json(
        &test_scores,
        &serde_json::json!({
            "input": input.kind.name(),
            "frames": input.frames,
            "init": request.init.name(),
            "steps": trainer.step(),
            "test_set": config.test.synth,
            "evaluation": test,
        }),
    )?;
    Ok(TrainSummary {
        steps: trainer.step(),
        minutes: started.elapsed().as_secs_f64() / 60.0,
        weights,
        curves,
        input,
        validation: trainer.last_evaluation().cloned(),
        test,
        test_results,
        test_scores,
    })
}

fn write_json(path: &Path, value: &serde_json::Value) -> Result<(), RunError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| RunError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    bevworld_graph::io::write_atomic_now(path, text.as_bytes()).map_err(|e| RunError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}
