//! `bevworld train tokenizer`: parses the flags into a `TrainRequest` and runs it
//! (`bevworld_tokenizer_train::train`), with a progress bar; the run itself is the library's.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Result, anyhow, bail};
use bevworld_tokenizer::Modality;
use bevworld_tokenizer_train::{
    LidarDraw, Overrides, Progress, RunError, Targets, TrainRequest, train,
};
use bevworld_training::{Observer, StepReport, Validation};
use clap::{Args, Subcommand};

#[derive(Subcommand)]
pub enum TrainCommand {
    /// Train the BEV tokenizer.
    Tokenizer(Box<TrainTokenizerArgs>),
    /// Train the world model (latent BEV sequence diffusion) on the tokenizer's latents of
    /// synthetic scenes: the paper's three stages, then one on counterfactual branches, in one
    /// run. The latent caches are exported first if missing.
    WorldModel(TrainWorldModelArgs),
    /// Train the detection and motion heads on BEV features of annotated synthetic scenes (the
    /// paper's pretraining table): the pillar statistics, the tokenizer's latent or its fused
    /// feature, one frame or two; scored on the test set with the nuScenes detection metrics
    /// and minADE/minFDE. The features are exported first if missing.
    Detector(super::detector_train::TrainDetectorArgs),
}

#[derive(Args)]
pub struct TrainWorldModelArgs {
    /// Training config.
    #[arg(long, default_value = "configs/models/train-world-model-tiny.yaml")]
    pub config: PathBuf,
    /// Run folder: checkpoints, metrics.csv, curves.png, the configs used, and the weights
    /// (`<model>.bpk` with `<model>.meta.json`) at the end.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from the run folder's newest checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Stop after this step (counted over all stages), keeping the config's stages and
    /// schedules; `--resume` continues it.
    #[arg(long, value_name = "STEP")]
    pub until: Option<usize>,
    /// Export the latent caches and stop.
    #[arg(long)]
    pub prepare_only: bool,
    /// Worker threads for a step's micro-batches and for validation (default: the available
    /// cores). The run's results do not depend on it.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Log a training row to metrics.csv every N steps.
    #[arg(long, default_value_t = 10)]
    pub log_every: usize,
    /// Ablation: the diffusion target, overriding the model config's (`epsilon` also turns
    /// zero terminal SNR off, under which it cannot be sampled).
    #[arg(long, value_name = "epsilon|v|x0")]
    pub target: Option<String>,
    /// Ablation: diffuse the residual over the ego-warped current latent (true) or the latent
    /// itself (false), overriding the model config's `residual_over_ego_warp`.
    #[arg(long, value_name = "true|false")]
    pub residual: Option<bool>,
    /// Ablation: the horizon (s) at which the warp's weight in the residual's base reaches 0,
    /// overriding the model config's `ego_warp_fade_s`; `none` keeps the full warp.
    #[arg(long, value_name = "SECONDS|none")]
    pub ego_warp_fade: Option<String>,
    /// Ablation: the future frames' tokens embed their ego-warped current latent (true) or not,
    /// overriding the model config's `ego_warp_input`.
    #[arg(long, value_name = "true|false")]
    pub ego_warp_input: Option<bool>,
    /// Ablation: keep only these stages, numbered from 1 (e.g. 3: the long-sequence stage
    /// alone).
    #[arg(long, value_delimiter = ',', value_name = "N,..")]
    pub stages: Option<Vec<usize>>,
    /// Ablation: the steps of each kept stage.
    #[arg(long, value_delimiter = ',', value_name = "STEPS,..")]
    pub stage_steps: Option<Vec<usize>>,
    /// Start from these trained weights (a world model's `.bpk` with its `.meta.json`),
    /// overriding the config's `init`: e.g. the same fine-tune from other weights, its control.
    #[arg(long, value_name = "WEIGHTS")]
    pub init: Option<PathBuf>,
    /// Weight the loss where the residual over the ego warp moves, overriding the config's
    /// `moving_weight`: a moving cell counts `1 + EXTRA` times, a cell moves past THRESHOLD
    /// (the standardised residual), e.g. `4,3` as `finetune-world-model-moving-tiny.yaml`.
    #[arg(long, value_name = "EXTRA,THRESHOLD")]
    pub moving_weight: Option<String>,
    /// Which coarse tokens a model with fine tokens opens, overriding its config's
    /// `fine_tokens.select`: a token opens where a cell's context change passes THRESHOLD,
    /// dilated by DILATE tokens, e.g. `8,1`.
    #[arg(long, value_name = "THRESHOLD,DILATE")]
    pub fine_select: Option<String>,
}

#[derive(Args)]
pub struct TrainTokenizerArgs {
    /// Training config.
    #[arg(long, default_value = "configs/models/train-tokenizer-tiny.yaml")]
    pub config: PathBuf,
    /// Run folder: checkpoints, metrics.csv, the configs used, and tokenizer.bpk at the end.
    #[arg(long)]
    pub out: PathBuf,
    /// Continue from the run folder's newest checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Override the config's step count; the cosine decay then ends at the last step (the
    /// config's `optimizer.decay_steps`, 9,200 in the committed tiny config, is set aside), so
    /// `--steps 9200` runs that config's whole schedule.
    #[arg(long)]
    pub steps: Option<usize>,
    /// Stop after this step, keeping the config's schedule: the run equals the first N steps
    /// of the full run (for ablations and quick comparisons), and `--resume` continues it.
    #[arg(long, value_name = "STEP")]
    pub until: Option<usize>,
    /// Train on this dataset instead of the config's synthetic training set.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Validate on this dataset instead of the config's synthetic validation set.
    #[arg(long)]
    pub val: Option<PathBuf>,
    /// torchvision's VGG16 weights for the perceptual term (overrides the config's
    /// `perceptual_weights`).
    #[arg(long)]
    pub vgg: Option<PathBuf>,
    /// Train an ablation tokenizer that reads and renders only `camera` or only `lidar`
    /// (`camera,lidar` is the full model), overriding the model config's `modalities`. A
    /// resumed run keeps the modalities it was started with.
    #[arg(long, value_name = "camera|lidar|camera,lidar")]
    pub modalities: Option<String>,
    /// Peak learning rate of AdamW, overriding the config's `optimizer.lr` (1.5e-3 in the
    /// committed tiny config). The modality ablation and the nuScenes keyframe fit were
    /// measured at 1e-3, the committed rate before the moving average.
    #[arg(long, value_name = "LR")]
    pub lr: Option<f64>,
    /// How each step draws its LiDAR rays, overriding the config's `rays.lidar_draw`: every
    /// return alike, or with probability proportional to its range.
    #[arg(long, value_name = "uniform|by_range")]
    pub lidar_draw: Option<String>,
    /// The share of each step's LiDAR rays drawn from the returns on annotated vehicles,
    /// overriding the config's `rays.lidar_vehicle_share` (0: every ray as `--lidar-draw`
    /// draws it; 0.25 in `finetune-tokenizer-vehicles-tiny.yaml`).
    #[arg(long, value_name = "SHARE")]
    pub lidar_vehicle_share: Option<f64>,
    /// Weight of the L1 loss between rendered and input RGB (in [0, 1]), overriding the
    /// config's `loss.rgb_l1` (0.5 in the committed tiny config).
    #[arg(long, value_name = "W")]
    pub rgb_l1: Option<f64>,
    /// Weight of the mean squared RGB error, the error PSNR measures, overriding the config's
    /// `loss.rgb_l2` (5 in the committed tiny config; 0: off). The nuScenes keyframe fit was
    /// measured with `--rgb-l1 1 --rgb-l2 0`, RGB L1 alone.
    #[arg(long, value_name = "W")]
    pub rgb_l2: Option<f64>,
    /// Weight of the L1 loss on the LiDAR rays' rendered depth, in metres, overriding the
    /// config's `loss.lidar_l1`. The synthetic config's 0.025 suits its near returns; a real
    /// sweep's Chamfer rests on its sparse far returns, which want more.
    #[arg(long, value_name = "W")]
    pub lidar_l1: Option<f64>,
    /// Weight of the distortion loss on the LiDAR rays' render weights (Mip-NeRF 360),
    /// overriding the config's `loss.lidar_distortion` (0: off). It pulls each ray's weight
    /// onto one surface, so that a ray at an object's edge does not put its point between the
    /// object and what lies behind it.
    #[arg(long, value_name = "W")]
    pub lidar_distortion: Option<f64>,
    /// Weight of the termination loss on the LiDAR rays' render weights, overriding the
    /// config's `loss.lidar_termination` (0: off): the negative log-likelihood of each return
    /// under its ray's termination distribution, which asks for free space up to the return and
    /// a stop there, not only for the right mean depth.
    #[arg(long, value_name = "W")]
    pub lidar_termination: Option<f64>,
    /// Weight of the sparsity prior on the field's opacity at every voxel centre, overriding
    /// the config's `loss.density_sparsity` (0: off; `finetune-tokenizer-sparse-tiny.yaml`
    /// sets it): it asks for empty air, which empty-space skipping then skips.
    #[arg(long, value_name = "W")]
    pub density_sparsity: Option<f64>,
    /// Keep an exponential moving average of the parameters with this decay per step, and
    /// validate and ship it, overriding the config's `ema_decay` (0.995 in the committed tiny
    /// config); `off` ships the last iterate. The modality ablation and the nuScenes fit were
    /// measured with `off`.
    #[arg(long, value_name = "D|off")]
    pub ema_decay: Option<String>,
    /// Cast the camera rays on the 1/N grid of each image, overriding the model config's
    /// `render.camera_stride` (a power of two dividing the image size; the RGB upsampler gets
    /// one doubling per factor of two). A resumed run keeps the stride it was started with.
    #[arg(long, value_name = "N")]
    pub camera_stride: Option<usize>,
    /// Exit with status 1 unless the final validation PSNR reaches this many dB (an automated
    /// quality check, e.g. the nuScenes keyframe fit's 25 dB).
    #[arg(long, value_name = "DB")]
    pub require_psnr: Option<f64>,
    /// Exit with status 1 unless the final validation Chamfer is at most this many m².
    #[arg(long, value_name = "M2")]
    pub require_chamfer: Option<f64>,
    /// Worker threads for a step's frames and for validation (default: the available cores).
    /// The run's results do not depend on it.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Log a training row to metrics.csv every N steps.
    #[arg(long, default_value_t = 10)]
    pub log_every: usize,
}

/// The flag that sets each config field an override can refuse, so that the refusal names the
/// flag the user typed.
const FLAG_OF_FIELD: [(&str, &str); 11] = [
    ("optimizer.lr", "--lr"),
    ("rays.lidar_vehicle_share", "--lidar-vehicle-share"),
    ("ema_decay", "--ema-decay"),
    ("loss.rgb_l1", "--rgb-l1"),
    ("loss.rgb_l2", "--rgb-l2"),
    ("loss.lidar_l1", "--lidar-l1"),
    ("loss.lidar_distortion", "--lidar-distortion"),
    ("loss.lidar_termination", "--lidar-termination"),
    ("loss.density_sparsity", "--density-sparsity"),
    ("render.camera_stride", "--camera-stride"),
    ("steps", "--steps"),
];

pub fn run(command: &TrainCommand) -> Result<ExitCode> {
    match command {
        TrainCommand::Tokenizer(args) => tokenizer(args),
        TrainCommand::WorldModel(args) => world_model(args),
        TrainCommand::Detector(args) => super::detector_train::run(args),
    }
}

fn request(args: &TrainTokenizerArgs) -> Result<TrainRequest> {
    let modalities = args
        .modalities
        .as_deref()
        .map(Modality::parse_list)
        .transpose()
        .map_err(|e| anyhow!("--modalities: {e}"))?;
    let ema_decay = match args.ema_decay.as_deref() {
        None => None,
        Some("off") => Some(None),
        Some(number) => Some(Some(number.parse::<f64>().map_err(|_| {
            anyhow!("--ema-decay: '{number}' is neither a number nor 'off'")
        })?)),
    };
    let lidar_draw = args
        .lidar_draw
        .as_deref()
        .map(str::parse::<LidarDraw>)
        .transpose()
        .map_err(|e| anyhow!("--lidar-draw: {e}"))?;
    Ok(TrainRequest {
        config: args.config.clone(),
        out: args.out.clone(),
        resume: args.resume,
        overrides: Overrides {
            steps: args.steps,
            modalities,
            camera_stride: args.camera_stride,
            lr: args.lr,
            ema_decay,
            lidar_draw,
            lidar_vehicle_share: args.lidar_vehicle_share,
            rgb_l1: args.rgb_l1,
            rgb_l2: args.rgb_l2,
            lidar_l1: args.lidar_l1,
            lidar_distortion: args.lidar_distortion,
            lidar_termination: args.lidar_termination,
            density_sparsity: args.density_sparsity,
            vgg: args.vgg.clone(),
        },
        until: args.until,
        data: args.data.clone(),
        val: args.val.clone(),
        threads: args.threads,
        log_every: args.log_every,
        targets: Targets {
            psnr_db: args.require_psnr,
            chamfer_m2: args.require_chamfer,
        },
    })
}

fn tokenizer(args: &TrainTokenizerArgs) -> Result<ExitCode> {
    let request = request(args)?;
    let (_, device) = bevworld_device::from_env()?;
    let mut bar = Bar::default();
    let summary = match train(&request, &device, &mut bar) {
        Ok(summary) => summary,
        Err(RunError::Override { problem }) => {
            bar.abandon();
            match FLAG_OF_FIELD
                .iter()
                .find(|(field, _)| *field == problem.field)
            {
                Some((_, flag)) => bail!("{flag}: {problem}"),
                None => bail!("{problem}"),
            }
        }
        Err(error) => {
            bar.abandon();
            return Err(error.into());
        }
    };
    bar.finish();
    println!(
        "{} steps in {:.1} min; weights {}; log {}; curves {}",
        summary.steps,
        summary.minutes,
        summary.weights.display(),
        summary.log.display(),
        summary.curves.display()
    );
    if summary.missed.is_empty() {
        return Ok(ExitCode::SUCCESS);
    }
    for line in &summary.missed {
        eprintln!("target missed: {line}");
    }
    Ok(ExitCode::FAILURE)
}

fn world_model(args: &TrainWorldModelArgs) -> Result<ExitCode> {
    use bevworld_world_model_train as wm;
    let config = wm::TrainWorldModelConfig::from_yaml_file(&args.config)?;
    if args.until == Some(0) {
        bail!("--until 0: a run of no steps would ship untrained weights");
    }
    let request = wm::TrainRequest {
        config: args.config.clone(),
        out: args.out.clone(),
        resume: args.resume,
        until: args.until,
        threads: args.threads,
        log_every: args.log_every,
        // The command as a user types it, without the binary's path.
        command: std::iter::once("bevworld".to_string())
            .chain(std::env::args().skip(1))
            .collect::<Vec<_>>()
            .join(" "),
        overrides: wm::Overrides {
            target: args
                .target
                .as_deref()
                .map(|t| match t {
                    "epsilon" => Ok(bevworld_world_model::Target::Epsilon),
                    "v" => Ok(bevworld_world_model::Target::V),
                    "x0" => Ok(bevworld_world_model::Target::X0),
                    other => Err(anyhow!("--target: '{other}' is not epsilon, v or x0")),
                })
                .transpose()?,
            residual_over_ego_warp: args.residual,
            ego_warp_fade_s: args
                .ego_warp_fade
                .as_deref()
                .map(|text| match text {
                    "none" => Ok(None),
                    seconds => seconds.parse::<f64>().map(Some).map_err(|_| {
                        anyhow!("--ego-warp-fade: '{seconds}' is not a number of seconds or none")
                    }),
                })
                .transpose()?,
            ego_warp_input: args.ego_warp_input,
            stages: args.stages.clone(),
            stage_steps: args.stage_steps.clone(),
            init: args.init.clone(),
            moving_weight: args
                .moving_weight
                .as_deref()
                .map(|text| {
                    let numbers: Vec<f64> = text
                        .split(',')
                        .map(|n| n.trim().parse::<f64>())
                        .collect::<Result<_, _>>()
                        .map_err(|_| anyhow!("--moving-weight: '{text}' is not EXTRA,THRESHOLD"))?;
                    match numbers[..] {
                        [extra, threshold] => {
                            Ok(wm::moving_weight::MovingWeight { extra, threshold })
                        }
                        _ => Err(anyhow!("--moving-weight: '{text}' is not EXTRA,THRESHOLD")),
                    }
                })
                .transpose()?,
            fine_select: args
                .fine_select
                .as_deref()
                .map(|text| {
                    let refused = || anyhow!("--fine-select: '{text}' is not THRESHOLD,DILATE");
                    let (threshold, dilate) = text.split_once(',').ok_or_else(refused)?;
                    Ok::<_, anyhow::Error>(bevworld_world_model::FineTokenRule {
                        threshold: threshold.trim().parse().map_err(|_| refused())?,
                        dilate: dilate.trim().parse().map_err(|_| refused())?,
                    })
                })
                .transpose()?,
        },
    };
    // The flags are checked against the configs before the caches are exported, which takes
    // minutes on a fresh machine.
    let (effective, model) = wm::effective_configs(&request)?;
    // The branched cache only where a stage of this run reads it.
    let caches: Vec<_> = [&config.train, &config.val]
        .into_iter()
        .chain(effective.branches_in_use())
        .collect();
    for cache in &caches {
        super::latent_cache::ensure(cache, &config.tokenizer_model, &config.tokenizer_weights)?;
    }
    if args.prepare_only {
        let ready: Vec<String> = caches
            .iter()
            .map(|c| c.latents.display().to_string())
            .collect();
        println!("latent caches ready: {}", ready.join(", "));
        return Ok(ExitCode::SUCCESS);
    }
    let (_, device) = bevworld_device::from_env()?;
    let mut bar = WorldModelBar::default();
    let summary = match wm::train(&request, &device, &mut bar) {
        Ok(summary) => summary,
        Err(error) => {
            bar.0.abandon();
            return Err(error.into());
        }
    };
    bar.0.finish();
    println!(
        "{} steps in {:.1} min; weights {}; log {}; curves {}",
        summary.steps,
        summary.minutes,
        summary.weights.display(),
        summary.log.display(),
        summary.curves.display()
    );
    println!("{}", summary.scores.markdown(None, model.frame_interval_s));
    Ok(ExitCode::SUCCESS)
}

/// A world-model run on the terminal: a bar of steps with the loss, a line per validation.
#[derive(Default)]
struct WorldModelBar(Bar);

impl Observer for WorldModelBar {
    fn stepped(&mut self, report: &StepReport) {
        let bar = self.0.shown();
        bar.set_position(report.step as u64);
        bar.set_message(format!(
            "stage {} loss {:.4}",
            report.term("stage").unwrap_or(0.0),
            report.loss
        ));
    }

    fn validated(&mut self, step: usize, validation: &Validation) {
        let line = format!(
            "step {step}: {}: latent L1 at 1 s {} (ego-warp {}), at 3 s {} (ego-warp {}, copy-last {})",
            validation.label,
            shown(validation.score("l1_1.0s"), 4),
            shown(validation.score("ego_warp_1.0s"), 4),
            shown(validation.score("l1_3.0s"), 4),
            shown(validation.score("ego_warp_3.0s"), 4),
            shown(validation.score("copy_last_3.0s"), 4),
        );
        tracing::info!(step, "{line}");
        self.0.shown().println(line);
    }
}

impl bevworld_world_model_train::Progress for WorldModelBar {
    fn prepared(&mut self, message: &str) {
        Progress::prepared(&mut self.0, message);
    }

    fn started(&mut self, step: usize, stop: usize, resumed: bool) {
        Progress::started(&mut self.0, step, stop, resumed);
    }
}

/// The run's progress on the terminal: the data loading, then a bar of steps with the step's
/// loss, and a line per validation.
#[derive(Default)]
struct Bar {
    bar: Option<indicatif::ProgressBar>,
}

impl Bar {
    fn shown(&mut self) -> &indicatif::ProgressBar {
        self.bar
            .get_or_insert_with(|| indicatif::ProgressBar::new(0).with_message("preparing frames"))
    }

    fn abandon(&self) {
        if let Some(bar) = &self.bar {
            bar.abandon();
        }
    }

    fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish();
        }
    }
}

impl Observer for Bar {
    fn stepped(&mut self, report: &StepReport) {
        let bar = self.shown();
        bar.set_position(report.step as u64);
        bar.set_message(format!(
            "loss {:.4} (rgb {}, lidar {} m)",
            report.loss,
            shown(report.term("loss_rgb"), 4),
            shown(report.term("loss_lidar"), 3)
        ));
    }

    fn validated(&mut self, step: usize, validation: &Validation) {
        let line = format!(
            "step {step}: {}: PSNR {} dB, SSIM {}, Chamfer {} m² ({} frames{})",
            validation.label,
            shown(validation.score("psnr_db"), 2),
            shown(validation.score("ssim"), 3),
            shown(validation.score("chamfer_m2"), 3),
            validation.frames,
            match validation.score("cameras_unscored") {
                Some(n) if n > 0.0 => format!(", {n} camera images unscored"),
                _ => String::new(),
            }
        );
        tracing::info!(step, "{line}");
        self.shown().println(line);
    }
}

impl Progress for Bar {
    fn loading(&mut self, done: usize, total: usize) {
        let bar = self.shown();
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    }

    fn prepared(&mut self, message: &str) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
        println!("{message}");
    }

    fn started(&mut self, step: usize, stop: usize, resumed: bool) {
        if resumed {
            println!("resumed at step {step}");
        }
        let bar = indicatif::ProgressBar::new(stop as u64);
        bar.set_position(step as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{bar:30} {pos}/{len} steps {elapsed_precise} eta {eta} {msg}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        self.bar = Some(bar);
    }
}

/// A figure with `decimals` digits, or "-" for a modality the model does not render.
fn shown(value: Option<f64>, decimals: usize) -> String {
    value.map_or_else(|| "-".into(), |v| format!("{v:.decimals$}"))
}
