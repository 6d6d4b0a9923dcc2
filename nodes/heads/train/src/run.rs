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

use bevworld_tokenizer::nodes::loaded_model::UNTRAINED;
use bevworld_tokenizer::{
    EncoderArrays, FrameInputs, Tokenizer, TokenizerConfig, load_weights, save_weights,
    weights_digest,
};

use crate::config::TrainDetectorConfig;
use crate::data::{DataError, DetectionSet, load_set};
use crate::encoder::{encode_maps, load_encoder_set};
use crate::evaluate::{Evaluation, predict, results_of};
use crate::trainer::{CURVES, DetectorTrainer, EncoderInLoop, TrainError, columns};

/// How the encoder that makes the features starts, the paper's pretraining comparison plus
/// what a user of the export gets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Init {
    /// The shipped tokenizer's exported features: the encoder frozen, only the heads learn.
    Frozen,
    /// The shipped tokenizer's encoder, fine-tuned with the heads (at
    /// `fine_tune_lr_fraction` of their rate).
    Tokenizer,
    /// The same encoder freshly initialised (from the run's seed), trained with the heads at
    /// their rate.
    Scratch,
}

impl Init {
    pub fn name(self) -> &'static str {
        match self {
            Init::Frozen => "frozen",
            Init::Tokenizer => "tokenizer",
            Init::Scratch => "scratch",
        }
    }

    /// Whether the encoder trains in the loop (and the sets' features are made by it, not
    /// exported).
    pub fn trains_encoder(self) -> bool {
        self != Init::Frozen
    }
}

/// The weights a trained encoder is written to, in the run folder: export with them
/// (`--set models.tiny.tokenizer.weights=RUN/tokenizer.bpk`) to feed the detector beside it.
pub const ENCODER_WEIGHTS: &str = "tokenizer.bpk";

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
    /// `loss.moving` instead of the config's.
    pub moving_weight: Option<f64>,
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
    if let Some(moving) = request.moving_weight {
        if !(moving.is_finite() && moving >= 1.0) {
            return Err(RunError::Input(format!(
                "--moving-weight {moving}: not ≥ 1, a moving agent counts at least as much as a standing one"
            )));
        }
        config.loss.moving = moving;
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
    let threads = request
        .threads
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let sets = if request.init.trains_encoder() {
        encoder_sets(request, &config, &detector, device)?
    } else {
        exported_sets(request, &config, &detector)?
    };
    let Sets {
        train: train_set,
        val: val_set,
        test: test_set,
        encoder,
    } = sets;
    let (mean, std) = train_set.channel_statistics();
    let mut input = InputSpec {
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
        let source = if request.init.trains_encoder() {
            config.tokenizer_model.clone()
        } else {
            config.train.folder(request.input)
        };
        return Err(RunError::Input(format!("{}: {problem}", source.display())));
    }
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
    let mut test_set = test_set;
    let mut test_arrays = None;
    if let Some(encoder) = encoder {
        let tokenizer = encoder.initial.fork(&autodiff).train();
        test_arrays = Some(encoder.test);
        trainer = trainer.with_encoder(EncoderInLoop::new(
            encoder.config,
            tokenizer,
            config.optimizer.adamw(),
            encoder.lr_fraction,
            encoder.train,
            encoder.val,
        ));
    }
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
    // A trained encoder is written beside the detector, and the detector reads its features.
    if let (Some(tokenizer), Some(arrays)) = (trainer.shipped_encoder(), &test_arrays) {
        let path = request.out.join(ENCODER_WEIGHTS);
        let written = |e: bevworld_tokenizer::WeightsError| RunError::Write {
            path: path.clone(),
            message: e.to_string(),
        };
        save_weights(&tokenizer, &path).map_err(written)?;
        input.weights_hash = weights_digest(&path).map_err(written)?;
        encode_maps(&tokenizer, input.kind, &mut test_set, arrays, device)
            .map_err(|e| RunError::Train(TrainError::Encoder(e)))?;
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

/// The three sets a run reads, and with the encoder in the loop, what it starts from.
struct Sets {
    train: DetectionSet,
    val: DetectionSet,
    test: DetectionSet,
    encoder: Option<EncoderStart>,
}

/// The encoder a run trains: its config and initial weights (on the inference device), its
/// rate, and every keyframe's encoder inputs.
struct EncoderStart {
    config: TokenizerConfig,
    initial: Tokenizer,
    lr_fraction: f64,
    train: Vec<EncoderArrays>,
    val: Vec<EncoderArrays>,
    test: Vec<EncoderArrays>,
}

/// The three sets' exported features and annotations (`--init frozen`).
fn exported_sets(
    request: &TrainRequest,
    config: &TrainDetectorConfig,
    detector: &DetectorConfig,
) -> Result<Sets, RunError> {
    let load = |set: &crate::config::FeatureSet| {
        load_set(&set.folder(request.input), &set.synth.dir, detector)
    };
    let train = load(&config.train)?;
    let val = load(&config.val)?;
    let test = load(&config.test)?;
    same_maker("validation", &val, &train)?;
    same_maker("test", &test, &train)?;
    Ok(Sets {
        train,
        val,
        test,
        encoder: None,
    })
}

/// The three sets read from their datasets with every keyframe's encoder inputs, and the
/// encoder's initial weights (`--init tokenizer|scratch`). The training and validation maps are
/// the initial encoder's, which fixes the standardisation for the whole run (a fresh encoder's
/// features are standardised like a trained one's).
fn encoder_sets(
    request: &TrainRequest,
    config: &TrainDetectorConfig,
    detector: &DetectorConfig,
    device: &Device,
) -> Result<Sets, RunError> {
    if request.input == InputKind::BevStats {
        return Err(RunError::Input(format!(
            "--init {} trains the tokenizer's encoder with the heads, but the pillar statistics have no encoder: read --input latent or feature",
            request.init.name()
        )));
    }
    let tokenizer_config = TokenizerConfig::from_yaml_file(&config.tokenizer_model)
        .map_err(|e| RunError::Input(e.to_string()))?;
    let (initial, weights_hash, lr_fraction) = match request.init {
        Init::Tokenizer => (
            load_weights(&tokenizer_config, &config.tokenizer_weights, device)
                .map_err(|e| RunError::Input(e.to_string()))?,
            weights_digest(&config.tokenizer_weights)
                .map_err(|e| RunError::Input(e.to_string()))?,
            config.fine_tune_lr_fraction,
        ),
        Init::Scratch | Init::Frozen => (
            tokenizer_config.init_seeded(config.seed, device),
            UNTRAINED.to_string(),
            1.0,
        ),
    };
    let inputs = FrameInputs::new(&tokenizer_config);
    let load = |set: &crate::config::FeatureSet| {
        load_encoder_set(
            &set.synth.dir,
            detector,
            &inputs,
            request.input,
            &tokenizer_config.name,
            &weights_hash,
        )
    };
    let (mut train, train_arrays) = load(&config.train)?;
    let (mut val, val_arrays) = load(&config.val)?;
    let (test, test_arrays) = load(&config.test)?;
    encode_maps(&initial, request.input, &mut train, &train_arrays, device)?;
    encode_maps(&initial, request.input, &mut val, &val_arrays, device)?;
    Ok(Sets {
        train,
        val,
        test,
        encoder: Some(EncoderStart {
            config: tokenizer_config,
            initial,
            lr_fraction,
            train: train_arrays,
            val: val_arrays,
            test: test_arrays,
        }),
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
