//! The noise schedule: ᾱ_t, the fraction of the clean latent's variance left at noise level
//! `t`. Level 0 is the clean latent (ᾱ_0 = 1, what condition frames carry); levels 1..=T are
//! the diffusion steps, so that `q(x_t | x_0) = N(√ᾱ_t x_0, (1 − ᾱ_t) I)`.

use crate::config::{DiffusionConfig, ScheduleKind};

#[derive(Clone, Debug, PartialEq)]
pub struct NoiseSchedule {
    /// ᾱ at levels 0..=T (index 0 is 1).
    alpha_bar: Vec<f64>,
}

impl NoiseSchedule {
    pub fn new(config: &DiffusionConfig) -> Self {
        let steps = config.steps.max(1);
        let mut alpha_bar = Vec::with_capacity(steps + 1);
        alpha_bar.push(1.0);
        match config.schedule {
            ScheduleKind::Linear => {
                // DDPM: β_t linear in t, ᾱ_t = Π_{s ≤ t} (1 − β_s).
                let mut product = 1.0;
                for t in 0..steps {
                    let f = if steps == 1 {
                        0.0
                    } else {
                        t as f64 / (steps - 1) as f64
                    };
                    let beta = config.beta_start + (config.beta_end - config.beta_start) * f;
                    product *= 1.0 - beta;
                    alpha_bar.push(product);
                }
            }
            ScheduleKind::Cosine => {
                // Nichol and Dhariwal 2021: ᾱ(t) = f(t) / f(0), f(t) = cos²((t/T + s)/(1 + s) · π/2),
                // with β_t = 1 − ᾱ_t/ᾱ_{t−1} clipped to 0.999 so that no step destroys everything
                // at once.
                let s = 0.008;
                let f = |t: f64| {
                    ((t / steps as f64 + s) / (1.0 + s) * std::f64::consts::FRAC_PI_2)
                        .cos()
                        .powi(2)
                };
                let mut product = 1.0;
                for t in 1..=steps {
                    let beta = (1.0 - f(t as f64) / f((t - 1) as f64)).clamp(0.0, 0.999);
                    product *= 1.0 - beta;
                    alpha_bar.push(product);
                }
            }
        }
        if config.zero_terminal_snr {
            rescale_zero_terminal_snr(&mut alpha_bar[1..]);
        }
        Self { alpha_bar }
    }

    /// T, the number of diffusion steps.
    pub fn steps(&self) -> usize {
        self.alpha_bar.len() - 1
    }

    /// ᾱ at level `t` (0 ≤ t ≤ T; beyond T, ᾱ_T).
    pub fn alpha_bar(&self, t: usize) -> f64 {
        self.alpha_bar[t.min(self.steps())]
    }

    /// The signal-to-noise ratio ᾱ / (1 − ᾱ) at level `t`.
    pub fn snr(&self, t: usize) -> f64 {
        let a = self.alpha_bar(t);
        a / (1.0 - a)
    }
}

/// Lin et al. 2024, Algorithm 1: shift and scale √ᾱ so that the last level is pure noise
/// (√ᾱ_T = 0) while the first keeps its value. Training then sees the level sampling starts
/// from, instead of a residual signal that sampling never has.
fn rescale_zero_terminal_snr(alpha_bar: &mut [f64]) {
    let (Some(&first), Some(&last)) = (alpha_bar.first(), alpha_bar.last()) else {
        return;
    };
    let (root_first, root_last) = (first.sqrt(), last.sqrt());
    let span = root_first - root_last;
    if span <= 0.0 {
        return;
    }
    for a in alpha_bar.iter_mut() {
        let root = (a.sqrt() - root_last) * root_first / span;
        *a = root * root;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::Target;

    fn config(schedule: ScheduleKind, zero: bool) -> DiffusionConfig {
        DiffusionConfig {
            steps: 1000,
            schedule,
            beta_start: 1e-4,
            beta_end: 0.02,
            zero_terminal_snr: zero,
            target: Target::V,
        }
    }

    #[test]
    fn alpha_bar_falls_monotonically_from_one() {
        for kind in [ScheduleKind::Linear, ScheduleKind::Cosine] {
            for zero in [false, true] {
                let s = NoiseSchedule::new(&config(kind, zero));
                assert_eq!(s.alpha_bar(0), 1.0);
                for t in 1..=s.steps() {
                    assert!(
                        s.alpha_bar(t) < s.alpha_bar(t - 1),
                        "{kind:?} zero={zero}: level {t}"
                    );
                }
                assert!(s.alpha_bar(s.steps()) >= 0.0);
            }
        }
    }

    #[test]
    fn linear_schedule_matches_its_product_by_hand() {
        let s = NoiseSchedule::new(&config(ScheduleKind::Linear, false));
        // ᾱ_1 = 1 − β_1, ᾱ_2 = (1 − β_1)(1 − β_2), β_2 = 1e-4 + (0.02 − 1e-4) / 999.
        let beta_2 = 1e-4 + (0.02 - 1e-4) / 999.0;
        assert!((s.alpha_bar(1) - (1.0 - 1e-4)).abs() < 1e-15);
        assert!((s.alpha_bar(2) - (1.0 - 1e-4) * (1.0 - beta_2)).abs() < 1e-15);
        // DDPM's well-known terminal value: ᾱ_1000 ≈ 4.04e-5.
        assert!(
            (s.alpha_bar(1000) - 4.04e-5).abs() < 1e-6,
            "{}",
            s.alpha_bar(1000)
        );
    }

    #[test]
    fn zero_terminal_snr_ends_in_pure_noise_and_keeps_the_first_level() {
        for kind in [ScheduleKind::Linear, ScheduleKind::Cosine] {
            let plain = NoiseSchedule::new(&config(kind, false));
            let zero = NoiseSchedule::new(&config(kind, true));
            assert_eq!(zero.alpha_bar(1000), 0.0);
            assert_eq!(zero.snr(1000), 0.0);
            assert!((zero.alpha_bar(1) - plain.alpha_bar(1)).abs() < 1e-12);
        }
    }
}
