//! `bevworld train detector`: the paper's pretraining experiment at our scale. The sets of the
//! config are made if missing and their features exported through the same graphs a user
//! exports with (`export_features.yaml` for the latent and the fused feature,
//! `export_bev_stats.yaml` for the pillar statistics); then the heads train on them
//! (`bevworld_heads_train::train`) and are scored once on the test set.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use bevworld_heads::InputKind;
use bevworld_heads_train::{FeatureSet, Init, TrainDetectorConfig, TrainRequest};
use bevworld_training::{Observer, StepReport, Validation};
use clap::{Args, ValueEnum};

use crate::commands::{contracts, graph_run};

/// The graph the tokenizer's features are exported with.
pub const FEATURES_GRAPH: &str = "configs/graphs/export_features.yaml";
/// The graph the pillar statistics are exported with.
pub const BEV_STATS_GRAPH: &str = "configs/graphs/export_bev_stats.yaml";

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum InputArg {
    /// The weight-free pillar statistics.
    #[value(name = "bev_stats")]
    BevStats,
    /// The tokenizer's 4-channel latent.
    Latent,
    /// The tokenizer's fused BEV feature.
    Feature,
}

impl InputArg {
    fn kind(self) -> InputKind {
        match self {
            InputArg::BevStats => InputKind::BevStats,
            InputArg::Latent => InputKind::Latent,
            InputArg::Feature => InputKind::Feature,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum InitArg {
    /// The shipped tokenizer's exported features, the encoder frozen: only the heads learn.
    Frozen,
    /// The shipped tokenizer's encoder, fine-tuned with the heads on images and pillars.
    Tokenizer,
    /// The same encoder freshly initialised, trained with the heads.
    Scratch,
}

#[derive(Args)]
pub struct TrainDetectorArgs {
    /// Training config.
    #[arg(long, default_value = "configs/models/train-detector-tiny.yaml")]
    pub config: PathBuf,
    /// Run folder: checkpoints, metrics.csv, curves.png, detector.bpk and its metadata, and
    /// test/ (results_nusc.json and scores.json on the test set); with --init tokenizer or
    /// scratch also tokenizer.bpk, the trained encoder whose features the detector reads.
    #[arg(long)]
    pub out: PathBuf,
    /// The BEV product the detector reads.
    #[arg(long, value_enum, default_value = "latent")]
    pub input: InputArg,
    /// 1: the current keyframe; 2: the previous keyframe as well, warped by the ego motion.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub frames: u8,
    /// How the encoder starts.
    #[arg(long, value_enum, default_value = "frozen")]
    pub init: InitArg,
    /// Continue the run in --out from its newest checkpoint.
    #[arg(long)]
    pub resume: bool,
    /// Steps instead of the config's.
    #[arg(long, value_name = "N")]
    pub steps: Option<usize>,
    /// How many times a moving agent's velocity and motion terms count, instead of the
    /// config's `loss.moving`.
    #[arg(long, value_name = "W")]
    pub moving_weight: Option<f64>,
    /// Worker threads (default: the cores).
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    #[arg(long, default_value_t = 10)]
    pub log_every: usize,
    /// Make the sets (and export their features, for --init frozen), then stop.
    #[arg(long)]
    pub prepare_only: bool,
}

/// Makes the set if it is missing, then exports the features of `input` unless its index
/// exists.
pub fn ensure_features(
    set: &FeatureSet,
    input: InputKind,
    config: &TrainDetectorConfig,
) -> Result<()> {
    set.synth
        .ensure()
        .with_context(|| format!("making the synthetic set {}", set.synth.dir.display()))?;
    if set
        .folder(input)
        .join(bevworld_heads_train::data::INDEX)
        .is_file()
    {
        return Ok(());
    }
    eprintln!(
        "exporting the {} of {} into {}",
        input.name(),
        set.synth.dir.display(),
        set.folder(input).display()
    );
    let data = format!("data={}", set.synth.dir.display());
    let graph = match input {
        InputKind::BevStats => {
            let set = [data, format!("out={}", set.folder(input).display())];
            graph_run::build_bound(
                Path::new(BEV_STATS_GRAPH),
                &contracts::DETECTOR_BEV_STATS,
                &set,
            )?
        }
        InputKind::Latent | InputKind::Feature => {
            let bundle =
                graph_run::bundle_name(Path::new(FEATURES_GRAPH), &contracts::DETECTOR_FEATURES)?;
            let set = [
                data,
                format!(
                    "models.{bundle}.tokenizer.config={}",
                    config.tokenizer_model.display()
                ),
                format!(
                    "models.{bundle}.tokenizer.weights={}",
                    config.tokenizer_weights.display()
                ),
                format!("out={}", set.folder(InputKind::Latent).display()),
                format!("fused_out={}", set.folder(InputKind::Feature).display()),
            ];
            graph_run::build_bound(
                Path::new(FEATURES_GRAPH),
                &contracts::DETECTOR_FEATURES,
                &set,
            )?
        }
    };
    graph_run::run_built(graph)?;
    Ok(())
}

pub fn run(args: &TrainDetectorArgs) -> Result<ExitCode> {
    let request = TrainRequest {
        config: args.config.clone(),
        input: args.input.kind(),
        frames: usize::from(args.frames),
        init: match args.init {
            InitArg::Frozen => Init::Frozen,
            InitArg::Tokenizer => Init::Tokenizer,
            InitArg::Scratch => Init::Scratch,
        },
        out: args.out.clone(),
        resume: args.resume,
        steps: args.steps,
        moving_weight: args.moving_weight,
        threads: args.threads,
        log_every: args.log_every,
        command: std::iter::once("bevworld".to_string())
            .chain(std::env::args().skip(1))
            .collect::<Vec<_>>()
            .join(" "),
    };
    if args.steps == Some(0) {
        return Err(super::refuse(
            "--steps 0: a run of no steps would ship untrained weights".to_string(),
        ));
    }
    // The flags and configs are checked before the sets are made, which takes minutes.
    let config = bevworld_heads_train::effective_config(&request)?;
    bevworld_heads::DetectorConfig::from_yaml_file(&config.model)?;
    if request.init.trains_encoder() && request.input == InputKind::BevStats {
        return Err(super::refuse(format!(
            "--init {} trains the tokenizer's encoder with the heads, but the pillar statistics (--input bev_stats) have no encoder: read --input latent or feature",
            request.init.name()
        )));
    }
    for set in [&config.train, &config.val, &config.test] {
        if request.init.trains_encoder() {
            // The encoder in the loop makes its own maps from the images and pillars.
            set.synth
                .ensure()
                .with_context(|| format!("making the synthetic set {}", set.synth.dir.display()))?;
        } else {
            ensure_features(set, request.input, &config)?;
        }
    }
    if args.prepare_only {
        println!("features ready for {}", request.input.name());
        return Ok(ExitCode::SUCCESS);
    }
    let (_, device) = bevworld_device::from_env()?;
    let mut bar = DetectorBar::default();
    let summary = match bevworld_heads_train::train(&request, &device, &mut bar) {
        Ok(summary) => summary,
        Err(error) => {
            if let Some(bar) = &bar.bar {
                bar.abandon();
            }
            return Err(error.into());
        }
    };
    if let Some(bar) = &bar.bar {
        bar.finish();
    }
    let test = &summary.test;
    println!(
        "{} steps in {:.1} min; weights {}; curves {}",
        summary.steps,
        summary.minutes,
        summary.weights.display(),
        summary.curves.display()
    );
    println!(
        "test set ({} keyframes): NDS {:.4} ± {:.4}, mAP {:.4} ± {:.4} (spread over scenes); minADE {:.3} m, minFDE {:.3} m, miss rate {:.3} over {} of {} agents (constant velocity: {:.3} / {:.3} m)",
        test.frames,
        test.detection.nd_score,
        test.scene_spread[0],
        test.detection.mean_ap,
        test.scene_spread[1],
        test.motion.min_ade,
        test.motion.min_fde,
        test.motion.miss_rate,
        test.motion.matched,
        test.motion.agents,
        test.motion.constant_velocity_ade,
        test.motion.constant_velocity_fde,
    );
    println!(
        "detections: {} (scored by `bevworld eval detector --data {} --results {}`); scores: {}",
        summary.test_results.display(),
        config.test.synth.dir.display(),
        summary.test_results.display(),
        summary.test_scores.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// A detector run on the terminal: a bar of steps with the loss, a line per validation.
#[derive(Default)]
struct DetectorBar {
    bar: Option<indicatif::ProgressBar>,
}

impl Observer for DetectorBar {
    fn stepped(&mut self, report: &StepReport) {
        let bar = self
            .bar
            .get_or_insert_with(|| indicatif::ProgressBar::new(0));
        bar.set_position(report.step as u64);
        bar.set_message(format!(
            "loss {:.4} (heatmap {:.4}, boxes {:.4}, motion {:.4})",
            report.loss,
            report.term("loss_heatmap").unwrap_or(0.0),
            report.term("loss_boxes").unwrap_or(0.0),
            report.term("loss_motion").unwrap_or(0.0),
        ));
    }

    fn validated(&mut self, step: usize, validation: &Validation) {
        let shown = |name: &str| {
            validation
                .score(name)
                .map_or_else(|| "-".to_string(), |v| format!("{v:.4}"))
        };
        let line = format!(
            "step {step}: validation ({} keyframes): NDS {}, mAP {}, mAVE {}, minADE {} m (constant velocity {} m)",
            validation.frames,
            shown("nds"),
            shown("map"),
            shown("mave"),
            shown("min_ade"),
            shown("cv_ade"),
        );
        tracing::info!(step, "{line}");
        match &self.bar {
            Some(bar) => bar.println(line),
            None => println!("{line}"),
        }
    }
}
