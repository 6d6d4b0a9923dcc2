//! DDIM sampling (Song et al. 2021) of the future frames, all of them in one network pass per
//! step, as in the paper.
//!
//! From the network's output at level `t` the sampler recovers the clean latent x̂₀ and the
//! noise ε̂, then steps to the previous level `s`:
//!
//! `x_s = √ᾱ_s x̂₀ + √(1 − ᾱ_s − σ²) ε̂ + σ z`,
//! `σ = η √((1 − ᾱ_s)/(1 − ᾱ_t)) √(1 − ᾱ_t/ᾱ_s)`,
//!
//! with `z` seeded noise; η = 0 is the deterministic DDIM, η = 1 DDPM's variance. The last step
//! goes to level 0 (ᾱ = 1), where `x_0 = x̂₀`.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::Target;
use crate::schedule::NoiseSchedule;
use crate::shrink::{ResidualShrink, ShrinkError};

/// Which of the T levels a run of `steps` steps visits (Lin et al. 2024, Table 2).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Spacing {
    /// `T, T − T/n, …`: always starts at T, where sampling's pure noise belongs.
    #[default]
    Trailing,
    /// `1 + k·⌊T/n⌋` descending: DDIM's original, which never visits T.
    Leading,
    /// `round(linspace(1, T, n))` descending.
    Linspace,
}

/// The sampler's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DdimConfig {
    /// Network evaluations, 1 to T.
    pub steps: usize,
    /// 0: deterministic.
    #[serde(default)]
    pub eta: f64,
    #[serde(default)]
    pub spacing: Spacing,
    /// Seed of the initial noise and of η's noise.
    #[serde(default)]
    pub seed: u64,
    /// After the last step, soft-threshold a residual model's sampled residual
    /// (`shrink.rs`); `None`: the sample as drawn.
    #[serde(default)]
    pub shrink: Option<ResidualShrink>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DdimError {
    #[error("sampler steps {steps}: must be 1 to T = {max}")]
    Steps { steps: usize, max: usize },
    #[error(
        "sampler eta {0}: must lie in [0, 1] (0 samples deterministically, 1 draws the fresh noise of DDPM; above 1 each step adds more noise than the process takes away, and the forecast diverges)"
    )]
    Eta(f64),
    #[error(transparent)]
    Shrink(#[from] ShrinkError),
}

impl DdimConfig {
    /// Deterministic sampling (η = 0) with trailing timesteps, as the shipped graphs sample:
    /// `steps` network passes from the noise of `seed`.
    pub fn deterministic(steps: usize, seed: u64) -> Self {
        Self {
            steps,
            eta: 0.0,
            spacing: Spacing::Trailing,
            seed,
            shrink: None,
        }
    }

    pub fn check(&self, schedule: &NoiseSchedule) -> Result<(), DdimError> {
        if self.steps == 0 || self.steps > schedule.steps() {
            return Err(DdimError::Steps {
                steps: self.steps,
                max: schedule.steps(),
            });
        }
        if !(self.eta.is_finite() && (0.0..=1.0).contains(&self.eta)) {
            return Err(DdimError::Eta(self.eta));
        }
        if let Some(shrink) = &self.shrink {
            shrink.check()?;
        }
        Ok(())
    }
}

/// The levels a run of `steps` steps visits, from the noisiest down, each with the level it
/// steps to (0 last). Levels are distinct and within 1..=T.
pub fn timesteps(total: usize, steps: usize, spacing: Spacing) -> Vec<(usize, usize)> {
    let steps = steps.clamp(1, total.max(1));
    let mut levels: Vec<usize> = match spacing {
        Spacing::Trailing => (0..steps)
            .map(|i| (total as f64 - i as f64 * total as f64 / steps as f64).round() as usize)
            .collect(),
        Spacing::Leading => {
            let stride = total / steps;
            (0..steps).rev().map(|k| 1 + k * stride).collect()
        }
        Spacing::Linspace => (0..steps)
            .rev()
            .map(|k| {
                if steps == 1 {
                    total
                } else {
                    (1.0 + k as f64 * (total - 1) as f64 / (steps - 1) as f64).round() as usize
                }
            })
            .collect(),
    };
    levels.iter_mut().for_each(|l| *l = (*l).clamp(1, total));
    levels.dedup();
    let next = levels.iter().skip(1).copied().chain([0]);
    levels.iter().copied().zip(next).collect()
}

/// √ᾱ and √(1 − ᾱ) at a level.
fn roots(schedule: &NoiseSchedule, level: usize) -> (f64, f64) {
    let a = schedule.alpha_bar(level);
    (a.sqrt(), (1.0 - a).max(0.0).sqrt())
}

/// `x_t = √ᾱ_t x₀ + √(1 − ᾱ_t) ε`, the forward process, with the network's training target;
/// item `b` of the batch (axis 0) at level `levels[b]`.
// x0, noise: [B, ...] -> ([B, ...], [B, ...])
pub fn noisy_and_target<const D: usize>(
    schedule: &NoiseSchedule,
    target: Target,
    x0: Tensor<D>,
    noise: Tensor<D>,
    levels: &[usize],
) -> (Tensor<D>, Tensor<D>) {
    let device = x0.device();
    let mut shape = [1; D];
    shape[0] = levels.len();
    let per_item = |f: &dyn Fn(usize) -> f64| -> Tensor<D> {
        let values: Vec<f32> = levels.iter().map(|&l| f(l) as f32).collect();
        Tensor::<1>::from_data(TensorData::new(values, [levels.len()]), &device).reshape(shape)
    };
    let signal = per_item(&|l| roots(schedule, l).0);
    let sigma = per_item(&|l| roots(schedule, l).1);
    let noisy = x0.clone() * signal.clone() + noise.clone() * sigma.clone();
    let wanted = match target {
        Target::Epsilon => noise,
        Target::X0 => x0,
        // v = √ᾱ ε − √(1 − ᾱ) x₀
        Target::V => noise * signal - x0 * sigma,
    };
    (noisy, wanted)
}

/// (x̂₀, ε̂) from the network's `output` for `noisy` at `level` (≥ 1).
pub fn clean_and_noise<const D: usize>(
    schedule: &NoiseSchedule,
    target: Target,
    noisy: Tensor<D>,
    output: Tensor<D>,
    level: usize,
) -> (Tensor<D>, Tensor<D>) {
    let (signal, sigma) = roots(schedule, level);
    match target {
        // x̂₀ = (x_t − √(1 − ᾱ) ε̂) / √ᾱ; the config refuses ε under ᾱ_T = 0.
        Target::Epsilon => {
            let x0 = (noisy - output.clone().mul_scalar(sigma)).div_scalar(signal.max(1e-12));
            (x0, output)
        }
        // ε̂ = (x_t − √ᾱ x̂₀) / √(1 − ᾱ), with 1 − ᾱ ≥ β₁ > 0 at every level ≥ 1.
        Target::X0 => {
            let noise = (noisy - output.clone().mul_scalar(signal)).div_scalar(sigma.max(1e-12));
            (output, noise)
        }
        // x̂₀ = √ᾱ x_t − √(1 − ᾱ) v̂, ε̂ = √(1 − ᾱ) x_t + √ᾱ v̂: no division, finite at ᾱ = 0.
        Target::V => {
            let x0 = noisy.clone().mul_scalar(signal) - output.clone().mul_scalar(sigma);
            let noise = noisy.mul_scalar(sigma) + output.mul_scalar(signal);
            (x0, noise)
        }
    }
}

/// One DDIM step from `level` to `previous` given x̂₀ and ε̂; `fresh` is the step's noise `z`
/// (used only when η > 0).
pub fn step<const D: usize>(
    schedule: &NoiseSchedule,
    clean: Tensor<D>,
    noise: Tensor<D>,
    level: usize,
    previous: usize,
    eta: f64,
    fresh: Option<Tensor<D>>,
) -> Tensor<D> {
    let a_t = schedule.alpha_bar(level);
    let a_s = schedule.alpha_bar(previous);
    let sigma = if eta > 0.0 && a_s > 0.0 && a_t < 1.0 {
        eta * ((1.0 - a_s) / (1.0 - a_t)).sqrt() * (1.0 - a_t / a_s).max(0.0).sqrt()
    } else {
        0.0
    };
    let direction = (1.0 - a_s - sigma * sigma).max(0.0).sqrt();
    let mut x = clean.mul_scalar(a_s.sqrt()) + noise.mul_scalar(direction);
    if sigma > 0.0
        && let Some(z) = fresh
    {
        x = x + z.mul_scalar(sigma);
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{DiffusionConfig, ScheduleKind};

    fn schedule(zero: bool) -> NoiseSchedule {
        NoiseSchedule::new(&DiffusionConfig {
            steps: 1000,
            schedule: ScheduleKind::Linear,
            beta_start: 1e-4,
            beta_end: 0.02,
            zero_terminal_snr: zero,
            target: Target::V,
        })
    }

    #[test]
    fn trailing_spacing_starts_at_t_and_ends_at_zero() {
        assert_eq!(
            timesteps(1000, 4, Spacing::Trailing),
            vec![(1000, 750), (750, 500), (500, 250), (250, 0)]
        );
        assert_eq!(timesteps(1000, 1, Spacing::Trailing), vec![(1000, 0)]);
        assert_eq!(
            timesteps(1000, 4, Spacing::Leading),
            vec![(751, 501), (501, 251), (251, 1), (1, 0)]
        );
        assert_eq!(
            timesteps(10, 3, Spacing::Linspace),
            vec![(10, 6), (6, 1), (1, 0)]
        );
        let all = timesteps(1000, 1000, Spacing::Trailing);
        assert_eq!(all.len(), 1000);
        assert!(all.windows(2).all(|w| w[0].0 == w[1].0 + 1));
    }

    fn scalar(v: f64) -> Tensor<1> {
        Tensor::from_floats([v as f32], &Device::flex())
    }

    fn value(t: Tensor<1>) -> f64 {
        f64::from(t.into_scalar::<f32>())
    }

    #[test]
    fn one_ddim_step_matches_the_formula_by_hand() {
        let s = schedule(false);
        // x_t = 0.3, ε̂ = 0.5 at level 500, stepping to 250, η = 0.
        let (a_t, a_s) = (s.alpha_bar(500), s.alpha_bar(250));
        let x0_hand = (0.3 - (1.0 - a_t).sqrt() * 0.5) / a_t.sqrt();
        let x_s_hand = a_s.sqrt() * x0_hand + (1.0 - a_s).sqrt() * 0.5;
        let (x0, eps) = clean_and_noise(&s, Target::Epsilon, scalar(0.3), scalar(0.5), 500);
        assert!((value(x0.clone()) - x0_hand).abs() < 1e-5);
        let x_s = step(&s, x0, eps, 500, 250, 0.0, None);
        assert!((value(x_s) - x_s_hand).abs() < 1e-5);
    }

    #[test]
    fn the_targets_invert_the_forward_process() {
        for zero in [false, true] {
            let s = schedule(zero);
            for target in [Target::Epsilon, Target::V, Target::X0] {
                if zero && target == Target::Epsilon {
                    continue;
                }
                for level in [1, 10, 500, 999, 1000] {
                    let (noisy, wanted) =
                        noisy_and_target(&s, target, scalar(0.7), scalar(-1.2), &[level]);
                    let (x0, eps) = clean_and_noise(&s, target, noisy, wanted, level);
                    let (x0, eps) = (value(x0), value(eps));
                    assert!(x0.is_finite() && eps.is_finite());
                    // At ᾱ_T = 0 the noisy latent holds no x₀ and the v target alone recovers it.
                    assert!(
                        (x0 - 0.7).abs() < 2e-3,
                        "{target:?} {level} zero={zero}: {x0}"
                    );
                    assert!(
                        (eps + 1.2).abs() < 2e-3,
                        "{target:?} {level} zero={zero}: {eps}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_step_from_pure_noise_is_finite_and_lands_on_the_prediction() {
        let s = schedule(true);
        assert_eq!(s.alpha_bar(1000), 0.0);
        // At t = T, x_T = ε exactly; a v-prediction of −x₀ there says x̂₀ = x₀.
        let (x0, eps) = clean_and_noise(&s, Target::V, scalar(0.4), scalar(-0.9), 1000);
        assert!((value(x0.clone()) - 0.9).abs() < 1e-6);
        assert!((value(eps.clone()) - 0.4).abs() < 1e-6);
        let one_step = step(&s, x0, eps, 1000, 0, 0.0, None);
        assert!((value(one_step) - 0.9).abs() < 1e-6);
    }
}
