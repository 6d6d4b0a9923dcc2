//! The training loop, the same for every model: steps until the plan's last step, a metrics
//! row every `log_every` steps, validation every `validate_every` steps and at the end, a
//! checkpoint every `checkpoint_every` steps and at the end. What a step, a validation and a
//! checkpoint are is the `Trainee`'s.

use std::path::Path;
use std::time::Instant;

use crate::metrics_log::{MetricsLog, MetricsLogError, Row};

/// What one optimiser step did.
#[derive(Clone, Debug, PartialEq)]
pub struct StepReport {
    /// Steps completed after this one.
    pub step: usize,
    pub lr: f64,
    pub loss: f64,
    /// The global gradient norm before clipping.
    pub grad_norm: f64,
    /// Each loss term the step took, by its metrics column (`loss_rgb`, …).
    pub terms: Vec<(&'static str, f64)>,
}

impl StepReport {
    /// The value of term `column`, when the step took it.
    pub fn term(&self, column: &str) -> Option<f64> {
        self.terms
            .iter()
            .find(|(name, _)| *name == column)
            .map(|(_, v)| *v)
    }
}

/// Scores by metrics column; `None` for a score that does not apply (a modality the model
/// does not render).
pub type Scores = Vec<(&'static str, Option<f64>)>;

/// One validation of one set of weights.
#[derive(Clone, Debug, PartialEq)]
pub struct Validation {
    /// The metrics log's phase: `val` for the weights the run ships.
    pub phase: &'static str,
    /// What was validated, for people ("the weights' moving average").
    pub label: &'static str,
    pub frames: usize,
    pub scores: Scores,
}

impl Validation {
    pub fn score(&self, column: &str) -> Option<f64> {
        self.scores
            .iter()
            .find(|(name, _)| *name == column)
            .and_then(|(_, v)| *v)
    }
}

/// A model's side of training.
pub trait Trainee {
    type Error: From<MetricsLogError>;

    /// Steps completed.
    fn step(&self) -> usize;

    /// One optimiser step.
    fn train_step(&mut self) -> Result<StepReport, Self::Error>;

    /// Validations on held-out data, the shipped weights' (phase `val`) last.
    fn validate(&mut self) -> Result<Vec<Validation>, Self::Error>;

    /// Writes a checkpoint of the current state into the run folder.
    fn save_checkpoint(&self, run: &Path) -> Result<(), Self::Error>;
}

/// When the loop logs, validates and checkpoints, and where it stops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoopPlan {
    /// The step after which the loop stops.
    pub stop: usize,
    pub log_every: usize,
    pub validate_every: usize,
    pub checkpoint_every: usize,
}

/// Hears of each step and validation (a progress bar, a console line); the loop works without
/// one.
pub trait Observer {
    fn stepped(&mut self, _report: &StepReport) {}
    fn validated(&mut self, _step: usize, _validation: &Validation) {}
}

/// No one listening.
impl Observer for () {}

/// Runs `trainee` up to `plan.stop`, logging into `log` (elapsed times from `started`) and
/// checkpointing into `run`. Returns the last validations, if any ran.
pub fn run_loop<T: Trainee>(
    trainee: &mut T,
    run: &Path,
    plan: LoopPlan,
    log: &mut MetricsLog,
    started: Instant,
    observer: &mut dyn Observer,
) -> Result<Option<Vec<Validation>>, T::Error> {
    let mut last_validation = None;
    while trainee.step() < plan.stop {
        let report = trainee.train_step()?;
        observer.stepped(&report);
        if report.step % plan.log_every.max(1) == 0 {
            let mut values = vec![
                ("lr", report.lr),
                ("loss", report.loss),
                ("grad_norm", report.grad_norm),
            ];
            values.extend(report.terms.iter().copied());
            log.append(&Row {
                step: report.step,
                phase: "train",
                elapsed_s: started.elapsed().as_secs_f64(),
                values,
            })?;
        }
        let last = report.step >= plan.stop;
        if report.step % plan.validate_every.max(1) == 0 || last {
            let validations = trainee.validate()?;
            for validation in &validations {
                observer.validated(report.step, validation);
                log.append(&Row {
                    step: report.step,
                    phase: validation.phase,
                    elapsed_s: started.elapsed().as_secs_f64(),
                    values: validation
                        .scores
                        .iter()
                        .filter_map(|(name, value)| value.map(|v| (*name, v)))
                        .collect(),
                })?;
            }
            last_validation = Some(validations);
        }
        if report.step % plan.checkpoint_every.max(1) == 0 || last {
            trainee.save_checkpoint(run)?;
        }
    }
    Ok(last_validation)
}
