//! `bevworld train tokenizer`: trains the tokenizer from a training config, with checkpoints
//! every N steps (`--resume` continues exactly), periodic validation, `metrics.csv`, and the
//! final weights at `RUN/tokenizer.bpk`.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use bevworld_tokenizer::train::checkpoint;
use bevworld_tokenizer::train::data::{ensure_synthetic, load_frames};
use bevworld_tokenizer::train::metrics_log::{MetricsLog, Row};
use bevworld_tokenizer::train::{LidarDraw, LossWeights, TrainConfig, Trainer, ValidationReport};
use bevworld_tokenizer::{FrameInputs, Modality, TokenizerConfig};
use clap::{Args, Subcommand};

#[derive(Subcommand)]
pub enum TrainCommand {
    /// Train the BEV tokenizer.
    Tokenizer(TrainTokenizerArgs),
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

/// The config's own check of the field `key` names, reported under the flag `--{flag}` that set
/// the value.
fn refuse_config_problem(config: &TrainConfig, flag: &str, key: &str) -> Result<()> {
    match config.problems().into_iter().find(|p| p.starts_with(key)) {
        Some(problem) => bail!("--{flag}: {problem}"),
        None => Ok(()),
    }
}

pub fn run(command: &TrainCommand) -> Result<ExitCode> {
    match command {
        TrainCommand::Tokenizer(args) => tokenizer(args),
    }
}

fn tokenizer(args: &TrainTokenizerArgs) -> Result<ExitCode> {
    let (mut config, mut model_config) = TrainConfig::from_yaml_file(&args.config)?;
    let run_model = args.out.join("tokenizer.yaml");
    if let Some(text) = &args.modalities {
        model_config.modalities =
            Modality::parse_list(text).map_err(|e| anyhow::anyhow!("--modalities: {e}"))?;
    }
    if let Some(stride) = args.camera_stride {
        model_config.render.camera_stride = stride;
        let problems = model_config.problems();
        if let Some(problem) = problems.iter().find(|p| p.contains("camera_stride")) {
            bail!("--camera-stride: {problem}");
        }
    }
    // A resumed run keeps the modalities and the ray grid it started with; naming others
    // would silently change the experiment halfway.
    if args.resume && run_model.exists() {
        let started = TokenizerConfig::from_yaml_file(&run_model)?;
        if args.modalities.is_some() && started.modalities != model_config.modalities {
            bail!(
                "--modalities: {} trained {:?}; resume it without --modalities, or choose another --out",
                args.out.display(),
                started.modalities
            );
        }
        if args.camera_stride.is_some()
            && started.render.camera_stride != model_config.render.camera_stride
        {
            bail!(
                "--camera-stride: {} trained on the 1/{} ray grid; resume it without --camera-stride, or choose another --out",
                args.out.display(),
                started.render.camera_stride
            );
        }
        model_config.modalities = started.modalities;
        model_config.render.camera_stride = started.render.camera_stride;
    }
    if let Some(steps) = args.steps {
        // A run given its own length decays over it: the fits and ablations that name a step
        // count keep the schedule they were measured with.
        config.steps = steps;
        config.optimizer.decay_steps = None;
    }
    if let Some(text) = &args.ema_decay {
        config.ema_decay = match text.as_str() {
            "off" => None,
            number => Some(number.parse::<f64>().map_err(|_| {
                anyhow::anyhow!("--ema-decay: '{number}' is neither a number nor 'off'")
            })?),
        };
        refuse_config_problem(&config, "ema-decay", "ema_decay:")?;
    }
    if let Some(lr) = args.lr {
        config.optimizer.lr = lr;
        refuse_config_problem(&config, "lr", "optimizer.lr:")?;
    }
    if let Some(text) = &args.lidar_draw {
        config.rays.lidar_draw = text
            .parse::<LidarDraw>()
            .map_err(|e| anyhow::anyhow!("--lidar-draw: {e}"))?;
    }
    let weight_flags: [(&str, Option<f64>, fn(&mut LossWeights) -> &mut f64); 5] = [
        ("rgb-l1", args.rgb_l1, |w| &mut w.rgb_l1),
        ("rgb-l2", args.rgb_l2, |w| &mut w.rgb_l2),
        ("lidar-l1", args.lidar_l1, |w| &mut w.lidar_l1),
        ("lidar-distortion", args.lidar_distortion, |w| {
            &mut w.lidar_distortion
        }),
        ("lidar-termination", args.lidar_termination, |w| {
            &mut w.lidar_termination
        }),
    ];
    for (flag, weight, field) in weight_flags {
        if let Some(weight) = weight {
            *field(&mut config.loss) = weight;
            let key = format!("loss.{}:", flag.replace('-', "_"));
            refuse_config_problem(&config, flag, &key)?;
        }
    }
    if let Some(vgg) = &args.vgg {
        config.perceptual_weights = Some(vgg.clone());
    }
    let has_checkpoint = checkpoint::latest(&args.out).is_ok();
    if has_checkpoint && !args.resume {
        bail!(
            "{} already holds checkpoints: pass --resume to continue that run, or choose another --out",
            args.out.display()
        );
    }
    // A run started without a weight average has none to continue; say how to resume it
    // before any data load.
    if let (true, Some(_), Ok((files, _))) =
        (args.resume, config.ema_decay, checkpoint::latest(&args.out))
        && !files.weight_average().is_file()
    {
        bail!(
            "--resume: {} was trained without a moving average of its weights ({} is missing); resume it with --ema-decay off, or with --config {}",
            args.out.display(),
            files.weight_average().display(),
            args.out.join("train.yaml").display()
        );
    }
    // The run folder is made once the data have loaded: a refused or missing dataset leaves
    // nothing behind.
    let train_dir = match &args.data {
        Some(dir) => dir.clone(),
        None => {
            ensure_synthetic(&config.data.train)?;
            config.data.train.dir.clone()
        }
    };
    let val_dir = match &args.val {
        Some(dir) => dir.clone(),
        None => {
            ensure_synthetic(&config.data.val)?;
            config.data.val.dir.clone()
        }
    };
    let inputs = FrameInputs::new(&model_config);
    let loading = indicatif::ProgressBar::new(0).with_message("preparing frames");
    let train = load_frames(&train_dir, &inputs, usize::MAX, |done, total| {
        loading.set_length(total as u64);
        loading.set_position(done as u64);
    })?;
    let val = load_frames(&val_dir, &inputs, config.validation_frames, |_, _| {})?;
    loading.finish_and_clear();
    println!(
        "training '{}' on {} frames of {} (validation: {} frames of {})",
        model_config.name,
        train.len(),
        train_dir.display(),
        val.len(),
        val_dir.display()
    );

    let (_, device) = bevworld_device::from_env()?;
    let mut trainer = Trainer::new(config.clone(), model_config.clone(), &device, train, val)?;
    if let Some(threads) = args.threads {
        trainer = trainer.with_threads(threads);
    }
    if args.resume {
        trainer = trainer.resume(&args.out)?;
        println!("resumed at step {}", trainer.step());
    }
    // The configs this run used, beside its weights: the training config with the command
    // line's overrides applied and naming the model config saved beside it, so that
    // `--config RUN/train.yaml --resume` continues the run.
    let mut recorded = config.clone();
    recorded.model = PathBuf::from("tokenizer.yaml");
    recorded.perceptual_weights = recorded
        .perceptual_weights
        .map(|p| std::path::absolute(&p).unwrap_or(p));
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let run_train = args.out.join("train.yaml");
    std::fs::write(&run_train, recorded.to_yaml()?)
        .with_context(|| format!("writing {}", run_train.display()))?;
    if model_config == TokenizerConfig::from_yaml_file(&config.model)? {
        // Resumed from the run folder's own config, the model config is already there;
        // copying a file onto itself would truncate it.
        if !same_file(&config.model, &run_model) {
            std::fs::copy(&config.model, &run_model).context("copying the model config")?;
        }
    } else {
        // Overridden on the command line (an ablation's modalities, another ray grid): the
        // config as trained, so `encode` and `render` build the model these weights fit.
        std::fs::write(&run_model, model_config.to_yaml()?)
            .with_context(|| format!("writing {}", run_model.display()))?;
    }
    let mut log = MetricsLog::open(&args.out, args.resume.then_some(trainer.step()))
        .with_context(|| format!("opening {}/metrics.csv", args.out.display()))?;

    let started = Instant::now();
    let progress = indicatif::ProgressBar::new(config.steps as u64);
    progress.set_position(trainer.step() as u64);
    progress.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:30} {pos}/{len} steps {elapsed_precise} eta {eta} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let mut last_validation = None;
    let stop = args.until.unwrap_or(config.steps).min(config.steps);
    while !trainer.is_done() && trainer.step() < stop {
        let report = match trainer.train_step() {
            Ok(report) => report,
            Err(error) => {
                progress.abandon();
                return Err(error.into());
            }
        };
        progress.set_position(report.step as u64);
        progress.set_message(format!(
            "loss {:.4} (rgb {}, lidar {} m)",
            report.loss,
            shown(report.loss_rgb, 4),
            shown(report.loss_lidar, 3)
        ));
        if report.step % args.log_every.max(1) == 0 {
            log.append(&Row {
                step: report.step,
                phase: "train",
                lr: Some(report.lr),
                loss: Some(report.loss),
                loss_rgb: report.loss_rgb,
                loss_rgb_squared: report.loss_rgb_squared,
                loss_lidar: report.loss_lidar,
                loss_distortion: report.loss_distortion,
                loss_termination: report.loss_termination,
                loss_perceptual: report.loss_perceptual,
                loss_gan: report.loss_gan,
                loss_discriminator: report.loss_discriminator,
                grad_norm: Some(report.grad_norm),
                elapsed_s: started.elapsed().as_secs_f64(),
                ..Row::default()
            })?;
        }
        let last = trainer.is_done() || trainer.step() >= stop;
        if report.step % config.validate_every == 0 || last {
            // With a moving average shipped, the last iterate's scores say what the average
            // adds; its row comes first, so that a run's last row is the shipped weights'.
            let shipped = trainer.validate();
            let reports = trainer
                .validate_iterate()
                .map(|i| ("val_iterate", "the last iterate", i))
                .into_iter()
                .chain([(
                    "val",
                    if config.ema_decay.is_some() {
                        "the weights' moving average"
                    } else {
                        "validation"
                    },
                    shipped,
                )]);
            for (phase, what, v) in reports {
                tracing::info!(
                    step = report.step,
                    psnr_db = v.psnr_db,
                    ssim = v.ssim,
                    chamfer_m2 = v.chamfer_m2,
                    "{what}"
                );
                progress.println(format!(
                    "step {}: {what}: PSNR {} dB, SSIM {}, Chamfer {} m² ({} frames)",
                    report.step,
                    shown(v.psnr_db, 2),
                    shown(v.ssim, 3),
                    shown(v.chamfer_m2, 3),
                    v.frames
                ));
                log.append(&Row {
                    step: report.step,
                    phase,
                    psnr_db: v.psnr_db,
                    ssim: v.ssim,
                    chamfer_m2: v.chamfer_m2,
                    elapsed_s: started.elapsed().as_secs_f64(),
                    ..Row::default()
                })?;
            }
            last_validation = Some(shipped);
        }
        if report.step % config.checkpoint_every == 0 || last {
            trainer.save_checkpoint(&args.out)?;
        }
    }
    progress.finish();
    let curves = args.out.join("curves.png");
    plot_curves(log.path(), &curves)?;
    let weights = args.out.join("tokenizer.bpk");
    trainer.save_weights(&weights)?;
    println!(
        "{} steps in {:.1} min; weights {}; log {}; curves {}",
        trainer.step(),
        started.elapsed().as_secs_f64() / 60.0,
        weights.display(),
        log.path().display(),
        curves.display()
    );
    let missed = missed_targets(last_validation, args.require_psnr, args.require_chamfer);
    if missed.is_empty() {
        return Ok(ExitCode::SUCCESS);
    }
    for line in &missed {
        eprintln!("target missed: {line}");
    }
    Ok(ExitCode::FAILURE)
}

/// Each required figure the final validation did not reach, as a sentence.
fn missed_targets(
    validation: Option<ValidationReport>,
    psnr_db: Option<f64>,
    chamfer_m2: Option<f64>,
) -> Vec<String> {
    let mut missed = Vec::new();
    let v = validation.unwrap_or(ValidationReport {
        frames: 0,
        psnr_db: None,
        ssim: None,
        chamfer_m2: None,
    });
    if let Some(target) = psnr_db {
        match v.psnr_db {
            Some(p) if p >= target => {}
            Some(p) => missed.push(format!("PSNR {p:.2} dB < {target} dB")),
            None => missed.push(format!("PSNR ≥ {target} dB required, none measured")),
        }
    }
    if let Some(target) = chamfer_m2 {
        match v.chamfer_m2 {
            Some(c) if c <= target => {}
            Some(c) => missed.push(format!("Chamfer {c:.3} m² > {target} m²")),
            None => missed.push(format!("Chamfer ≤ {target} m² required, none measured")),
        }
    }
    missed
}

/// Draws `curves.png` from `metrics.csv`: training loss (log scale, left), validation PSNR
/// (middle) and validation Chamfer (right).
fn plot_curves(csv: &std::path::Path, png: &std::path::Path) -> Result<()> {
    let text =
        std::fs::read_to_string(csv).with_context(|| format!("reading {}", csv.display()))?;
    let (mut loss, mut psnr, mut chamfer) = (Vec::new(), Vec::new(), Vec::new());
    for line in text.lines().skip(1) {
        let fields: Vec<&str> = line.split(',').collect();
        let number = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok());
        let Some(step) = number(0) else { continue };
        match fields.get(1) {
            Some(&"train") => loss.extend(number(3).map(|v| (step, v))),
            Some(&"val") => {
                psnr.extend(number(10).map(|v| (step, v)));
                chamfer.extend(number(12).map(|v| (step, v)));
            }
            _ => {}
        }
    }
    use bevworld_tokenizer::train::plot::{Series, plot};
    plot(
        png,
        &[
            Series {
                title: "TRAINING LOSS (LOG)",
                points: &loss,
                colour: [200, 60, 40],
                log_scale: true,
            },
            Series {
                title: "VAL PSNR (DB)",
                points: &psnr,
                colour: [40, 90, 200],
                log_scale: false,
            },
            Series {
                title: "VAL CHAMFER (M2, LOG)",
                points: &chamfer,
                colour: [30, 150, 60],
                log_scale: true,
            },
        ],
    )
    .with_context(|| format!("writing {}", png.display()))
}

/// A figure with `decimals` digits, or "-" for a modality the model does not render.
fn shown(value: Option<f64>, decimals: usize) -> String {
    value.map_or_else(|| "-".into(), |v| format!("{v:.decimals$}"))
}

/// Whether two paths name one existing file.
fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => false,
    }
}
