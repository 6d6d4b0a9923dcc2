//! A whole training run, as `bevworld train tokenizer` asks for one: the config and the
//! overrides its flags set (each checked under the field it sets, before anything is written),
//! the resume checks, the data, the loop (`bevworld_training::run_loop`), the configs recorded
//! beside the weights, the curves, and the quality targets. The command line only parses
//! flags and prints.

use std::path::{Path, PathBuf};
use std::time::Instant;

use bevworld_sensors::synth::SynthSetError;
use bevworld_tokenizer::config::ConfigError;
use bevworld_tokenizer::{FrameInputs, Modality, TokenizerConfig};
use bevworld_training::checkpoint;
use bevworld_training::curves::CurvesError;
use bevworld_training::metrics_log::MetricsLogError;
use bevworld_training::{ConfigProblem, LoopPlan, MetricsLog, Observer, plot_curves, run_loop};
use burn::prelude::*;

use crate::config::{LidarDraw, TrainConfig};
use crate::data::{DataError, TrainingFrame, load_frames};
use crate::trainer::{COLUMNS, CURVES, TrainError, Trainer, ValidationReport, files};

/// What a run changes in its config.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides {
    /// The run's length; the cosine then decays over it (`optimizer.decay_steps` is set aside).
    pub steps: Option<usize>,
    pub modalities: Option<Vec<Modality>>,
    pub camera_stride: Option<usize>,
    pub lr: Option<f64>,
    /// `Some(None)` turns the moving average off.
    pub ema_decay: Option<Option<f64>>,
    pub lidar_draw: Option<LidarDraw>,
    pub lidar_vehicle_share: Option<f64>,
    pub rgb_l1: Option<f64>,
    pub rgb_l2: Option<f64>,
    pub lidar_l1: Option<f64>,
    pub lidar_distortion: Option<f64>,
    pub lidar_termination: Option<f64>,
    pub density_sparsity: Option<f64>,
    /// torchvision's VGG16 weights for the perceptual term.
    pub vgg: Option<PathBuf>,
}

/// Figures the final validation must reach.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Targets {
    pub psnr_db: Option<f64>,
    pub chamfer_m2: Option<f64>,
}

/// One run, as asked for.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainRequest {
    pub config: PathBuf,
    /// The run folder: checkpoints, `metrics.csv`, the configs used, the weights at the end.
    pub out: PathBuf,
    pub resume: bool,
    pub overrides: Overrides,
    /// Stop after this step, keeping the config's schedule.
    pub until: Option<usize>,
    /// Datasets in place of the config's synthetic sets.
    pub data: Option<PathBuf>,
    pub val: Option<PathBuf>,
    pub threads: Option<usize>,
    pub log_every: usize,
    pub targets: Targets,
}

#[derive(Debug, thiserror::Error)]
pub enum RunError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A value an override set is refused; `problem.field` names the field it set.
    #[error("{problem}")]
    Override { problem: ConfigProblem },
    #[error(
        "{run} already holds checkpoints: pass --resume to continue that run, or choose another --out"
    )]
    Exists { run: PathBuf },
    /// Resuming with a setting other than the run's own would change the experiment halfway.
    #[error("{run} {started}; resume it without {flag}, or choose another --out")]
    ResumeChanges {
        run: PathBuf,
        flag: &'static str,
        started: String,
    },
    #[error(
        "{run} was trained without a moving average of its weights ({missing} is missing); resume it with --ema-decay off, or with --config {recorded}"
    )]
    NoAverageToResume {
        run: PathBuf,
        missing: PathBuf,
        recorded: PathBuf,
    },
    #[error("--until 0: a run of no steps would ship untrained weights")]
    NoSteps,
    #[error(transparent)]
    Set(#[from] SynthSetError),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error(transparent)]
    Log(#[from] MetricsLogError),
    #[error(transparent)]
    Curves(#[from] CurvesError),
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
}

impl From<checkpoint::CheckpointError> for RunError {
    fn from(error: checkpoint::CheckpointError) -> Self {
        Self::Train(TrainError::Checkpoint(error))
    }
}

/// What a finished run wrote and measured.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainSummary {
    pub steps: usize,
    pub minutes: f64,
    pub weights: PathBuf,
    pub log: PathBuf,
    pub curves: PathBuf,
    pub last_validation: Option<ValidationReport>,
    /// Each required figure the final validation did not reach, as a sentence.
    pub missed: Vec<String>,
}

/// What a run reports as it goes, beside each step and validation.
pub trait Progress: Observer {
    /// Frames prepared so far, of the training set.
    fn loading(&mut self, _done: usize, _total: usize) {}
    /// The data are ready.
    fn prepared(&mut self, _message: &str) {}
    /// The run continues from a checkpoint at `step`; it will stop after `stop`.
    fn started(&mut self, _step: usize, _stop: usize, _resumed: bool) {}
}

impl Progress for () {}

/// The config as this run trains it: the file's, then the overrides, each checked.
fn configs(request: &TrainRequest) -> Result<(TrainConfig, TokenizerConfig), RunError> {
    let (mut config, mut model) = TrainConfig::from_yaml_file(&request.config)?;
    let set = &request.overrides;
    if let Some(modalities) = &set.modalities {
        model.modalities = modalities.clone();
    }
    if let Some(stride) = set.camera_stride {
        model.render.camera_stride = stride;
        refuse(model.problems(), "render.camera_stride")?;
    }
    if let Some(steps) = set.steps {
        // A run given its own length decays over it: the fits and ablations that name a step
        // count keep the schedule they were measured with.
        config.steps = steps;
        config.optimizer.decay_steps = None;
    }
    if let Some(decay) = set.ema_decay {
        config.ema_decay = decay;
    }
    if let Some(lr) = set.lr {
        config.optimizer.lr = lr;
    }
    if let Some(draw) = set.lidar_draw {
        config.rays.lidar_draw = draw;
    }
    for (value, field) in [
        (set.rgb_l1, &mut config.loss.rgb_l1),
        (set.rgb_l2, &mut config.loss.rgb_l2),
        (set.lidar_l1, &mut config.loss.lidar_l1),
        (set.lidar_distortion, &mut config.loss.lidar_distortion),
        (set.lidar_termination, &mut config.loss.lidar_termination),
        (set.density_sparsity, &mut config.loss.density_sparsity),
        (
            set.lidar_vehicle_share,
            &mut config.rays.lidar_vehicle_share,
        ),
    ] {
        if let Some(value) = value {
            *field = value;
        }
    }
    if let Some(vgg) = &set.vgg {
        config.perceptual_weights = Some(vgg.clone());
    }
    // The file passed its own checks: what fails now, an override set.
    if let Some(problem) = config.problems().into_iter().next() {
        return Err(RunError::Override { problem });
    }
    Ok((config, model))
}

/// The first problem of `field`, as the override's error.
fn refuse(problems: Vec<ConfigProblem>, field: &str) -> Result<(), RunError> {
    match problems.into_iter().find(|p| p.field == field) {
        Some(problem) => Err(RunError::Override { problem }),
        None => Ok(()),
    }
}

/// Holds a resumed run to the modalities and the ray grid it started with.
fn keep_what_the_run_started_with(
    request: &TrainRequest,
    model: &mut TokenizerConfig,
) -> Result<(), RunError> {
    let recorded = request.out.join("tokenizer.yaml");
    if !(request.resume && recorded.exists()) {
        return Ok(());
    }
    let started = TokenizerConfig::from_yaml_file(&recorded)?;
    let set = &request.overrides;
    if set.modalities.is_some() && started.modalities != model.modalities {
        return Err(RunError::ResumeChanges {
            run: request.out.clone(),
            flag: "--modalities",
            started: format!("trained {:?}", started.modalities),
        });
    }
    if set.camera_stride.is_some() && started.render.camera_stride != model.render.camera_stride {
        return Err(RunError::ResumeChanges {
            run: request.out.clone(),
            flag: "--camera-stride",
            started: format!("trained on the 1/{} ray grid", started.render.camera_stride),
        });
    }
    model.modalities = started.modalities;
    model.render.camera_stride = started.render.camera_stride;
    Ok(())
}

/// The training and validation frames: the request's datasets, or the config's synthetic sets
/// (made on first use).
fn datasets(
    request: &TrainRequest,
    config: &TrainConfig,
    model: &TokenizerConfig,
    progress: &mut dyn Progress,
) -> Result<(Vec<TrainingFrame>, Vec<TrainingFrame>, String), RunError> {
    let folder = |given: &Option<PathBuf>, set: &bevworld_sensors::synth::SynthSet| match given {
        Some(dir) => Ok::<_, RunError>(dir.clone()),
        None => {
            set.ensure()?;
            Ok(set.dir.clone())
        }
    };
    let train_dir = folder(&request.data, &config.data.train)?;
    let val_dir = folder(&request.val, &config.data.val)?;
    let inputs = FrameInputs::new(model);
    let train = load_frames(&train_dir, &inputs, usize::MAX, |done, total| {
        progress.loading(done, total)
    })?;
    let val = load_frames(&val_dir, &inputs, config.validation_frames, |_, _| {})?;
    let message = format!(
        "training '{}' on {} frames of {} (validation: {} frames of {})",
        model.name,
        train.len(),
        train_dir.display(),
        val.len(),
        val_dir.display()
    );
    Ok((train, val, message))
}

/// Writes the configs this run trains with beside its weights: the training config with the
/// overrides applied, naming the model config saved beside it, so that
/// `--config RUN/train.yaml --resume` continues the run.
fn record_configs(
    out: &Path,
    config: &TrainConfig,
    model: &TokenizerConfig,
) -> Result<(), RunError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| RunError::Io { path, source }
    };
    std::fs::create_dir_all(out).map_err(io(out))?;
    let mut recorded = config.clone();
    recorded.model = PathBuf::from("tokenizer.yaml");
    recorded.perceptual_weights = recorded
        .perceptual_weights
        .map(|p| std::path::absolute(&p).unwrap_or(p));
    let train_yaml = out.join("train.yaml");
    bevworld_atomic_file::write(&train_yaml, recorded.to_yaml()?.as_bytes())
        .map_err(io(&train_yaml))?;
    // The model config as trained (with any override), so `encode` and `render` build the
    // model these weights fit.
    let model_yaml = out.join("tokenizer.yaml");
    bevworld_atomic_file::write(&model_yaml, model.to_yaml()?.as_bytes()).map_err(io(&model_yaml))
}

/// Runs `request` on `device`, reporting to `progress`.
pub fn train(
    request: &TrainRequest,
    device: &Device,
    progress: &mut dyn Progress,
) -> Result<TrainSummary, RunError> {
    if request.until == Some(0) {
        return Err(RunError::NoSteps);
    }
    let (config, mut model) = configs(request)?;
    keep_what_the_run_started_with(request, &mut model)?;
    // A checkpoint that fails its checks is still a run's: never start over it, and refuse to
    // resume from it before any data load.
    let latest = match (checkpoint::latest(&request.out), request.resume) {
        (Err(checkpoint::CheckpointError::None { .. }), _) => None,
        (_, false) => {
            return Err(RunError::Exists {
                run: request.out.clone(),
            });
        }
        (Err(error), true) => return Err(error.into()),
        (Ok(found), true) => Some(found),
    };
    // A run started without a weight average has none to continue; say how to resume it
    // before any data load.
    if let (Some(_), Some((files, _))) = (config.ema_decay, &latest) {
        let missing = files.file(files::WEIGHT_AVERAGE);
        if !missing.is_file() {
            return Err(RunError::NoAverageToResume {
                run: request.out.clone(),
                missing,
                recorded: request.out.join("train.yaml"),
            });
        }
    }
    // The weights a fine-tune starts from, looked for before minutes of data loading.
    if let Some(init) = &config.init
        && !init.is_file()
        && latest.is_none()
    {
        return Err(RunError::Override {
            problem: ConfigProblem::new("init", format!("{}: no such file", init.display())),
        });
    }
    // The run folder is made once the data have loaded: a refused or missing dataset leaves
    // nothing behind.
    let (train_frames, val_frames, message) = datasets(request, &config, &model, progress)?;
    progress.prepared(&message);
    let mut trainer = Trainer::new(
        config.clone(),
        model.clone(),
        device,
        train_frames,
        val_frames,
    )?;
    if let Some(threads) = request.threads {
        trainer = trainer.with_threads(threads);
    }
    if request.resume {
        trainer = trainer.resume(&request.out)?;
    } else if let Some(init) = &config.init {
        trainer = trainer.start_from(init)?;
    }
    record_configs(&request.out, &config, &model)?;
    let mut log = MetricsLog::open(
        &request.out,
        &COLUMNS,
        request.resume.then_some(trainer.step()),
    )?;
    let stop = request.until.unwrap_or(config.steps).min(config.steps);
    progress.started(trainer.step(), stop, request.resume);
    let started = Instant::now();
    let plan = LoopPlan {
        stop,
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
        progress,
    )?;
    let curves = request.out.join("curves.png");
    plot_curves(log.path(), &curves, &CURVES)?;
    let weights = request.out.join("tokenizer.bpk");
    trainer.save_weights(&weights)?;
    let last_validation = trainer.last_validation();
    Ok(TrainSummary {
        steps: trainer.step(),
        minutes: started.elapsed().as_secs_f64() / 60.0,
        missed: missed_targets(last_validation, request.targets),
        weights,
        log: log.path().to_path_buf(),
        curves,
        last_validation,
    })
}

/// Each required figure the final validation did not reach, as a sentence.
pub fn missed_targets(validation: Option<ValidationReport>, targets: Targets) -> Vec<String> {
    let mut missed = Vec::new();
    let (psnr, chamfer) = validation.map_or((None, None), |v| (v.psnr_db, v.chamfer_m2));
    if let Some(target) = targets.psnr_db {
        match psnr {
            Some(p) if p >= target => {}
            Some(p) => missed.push(format!("PSNR {p:.2} dB < {target} dB")),
            None => missed.push(format!("PSNR ≥ {target} dB required, none measured")),
        }
    }
    if let Some(target) = targets.chamfer_m2 {
        match chamfer {
            Some(c) if c <= target => {}
            Some(c) => missed.push(format!("Chamfer {c:.3} m² > {target} m²")),
            None => missed.push(format!("Chamfer ≤ {target} m² required, none measured")),
        }
    }
    missed
}
