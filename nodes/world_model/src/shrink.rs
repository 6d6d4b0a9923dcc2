//! The static world moved, not re-predicted: soft-thresholding of the sampled residual over
//! the ego warp.
//!
//! A residual model's future frame is `warp + r`, where the warp moves the current latent by
//! the ego's motion and `r` is what the sampler drew. One DDIM step draws the network's mean
//! residual, which is small but nowhere zero: the static world, which the warp already placed,
//! comes back slightly re-predicted, and a smoothed latent renders softer surfaces. Most of a
//! scene does not move, so the residual is sparse, and the estimate of a sparse signal under a
//! Laplace prior is the soft threshold (Donoho 1995):
//!
//! `r' = sign(r) · max(|r| − τ(h), 0)`,  `τ(h) = τ · max(1 − h / h_fade, 0)`,
//!
//! in standardised latent units, for a frame `h` seconds ahead. A cell whose residual is below
//! τ keeps the warped current latent; larger residuals (what moves, what comes into view) are
//! kept, less τ. τ falls to 0 at `h_fade`, where the warp is no longer the better guess of the
//! static world (bench/results/forecast.md: the forecast halves the warp's error at 3 s).

use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::ego_warp::linear_fade;

/// The threshold and the horizon at which it reaches 0.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ResidualShrink {
    /// τ at horizon 0, in standardised latent units (≥ 0).
    pub tau: f64,
    /// The horizon, in seconds, at which τ has fallen linearly to 0 (> 0).
    pub fade_s: f64,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ShrinkError {
    #[error("shrink tau {0}: must be a finite number >= 0")]
    Tau(f64),
    #[error("shrink fade_s {0}: must be a finite number of seconds > 0")]
    FadeS(f64),
}

impl ResidualShrink {
    pub fn check(&self) -> Result<(), ShrinkError> {
        if !(self.tau.is_finite() && self.tau >= 0.0) {
            return Err(ShrinkError::Tau(self.tau));
        }
        if !(self.fade_s.is_finite() && self.fade_s > 0.0) {
            return Err(ShrinkError::FadeS(self.fade_s));
        }
        Ok(())
    }

    /// τ(h) for a frame `horizon_s` seconds ahead.
    pub fn tau_at(&self, horizon_s: f64) -> f64 {
        self.tau * linear_fade(horizon_s, self.fade_s)
    }

    /// Soft-thresholds each future frame of `residual`, frame `k` (from 0) being
    /// `(k + 1) · frame_interval_s` ahead. A frame whose τ is 0 is returned untouched.
    // residual: [B, N, C', H, W] -> [B, N, C', H, W]
    pub fn apply(&self, residual: Tensor<5>, frame_interval_s: f64) -> Tensor<5> {
        let frames = residual.dims()[1];
        let shrunk = (0..frames)
            .map(|k| {
                let frame = residual.clone().narrow(1, k, 1); // [B, 1, C', H, W]
                let tau = self.tau_at((k + 1) as f64 * frame_interval_s) as f32;
                if tau > 0.0 {
                    // sign(r)·max(|r| − τ, 0) = r − clamp(r, −τ, τ)
                    frame.clone() - frame.clamp(-tau, tau)
                } else {
                    frame
                }
            })
            .collect();
        Tensor::cat(shrunk, 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(t: Tensor<5>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().expect("f32")
    }

    #[test]
    fn the_threshold_falls_linearly_to_zero_at_its_horizon_and_stays_there() {
        let s = ResidualShrink {
            tau: 0.3,
            fade_s: 3.0,
        };
        assert_eq!(s.tau_at(0.0), 0.3);
        assert!((s.tau_at(1.0) - 0.2).abs() < 1e-12);
        assert!((s.tau_at(2.5) - 0.05).abs() < 1e-12);
        assert_eq!(s.tau_at(3.0), 0.0);
        assert_eq!(s.tau_at(4.5), 0.0);
    }

    #[test]
    fn small_residuals_become_zero_and_large_ones_lose_tau_by_hand() {
        let device = Device::flex();
        // Two frames 0.5 s apart: τ(0.5) = 0.25, τ(1.0) = 0 with fade_s = 1.
        let s = ResidualShrink {
            tau: 0.5,
            fade_s: 1.0,
        };
        let raw = [0.1, -0.3, 0.5, -0.2, 0.1, -0.3, 0.5, -0.2];
        let residual = Tensor::<1>::from_floats(raw, &device).reshape([1, 2, 1, 2, 2]);
        let out = values(s.apply(residual, 0.5));
        let want = [0.0, -0.05, 0.25, 0.0, 0.1, -0.3, 0.5, -0.2];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-6, "{out:?} against {want:?}");
        }
    }

    #[test]
    fn bad_settings_are_refused_naming_the_field() {
        let bad = ResidualShrink {
            tau: -0.1,
            fade_s: 3.0,
        };
        assert!(bad.check().expect_err("tau").to_string().contains("tau"));
        let bad = ResidualShrink {
            tau: 0.25,
            fade_s: 0.0,
        };
        assert!(
            bad.check()
                .expect_err("fade")
                .to_string()
                .contains("fade_s")
        );
        let bad = ResidualShrink {
            tau: f64::NAN,
            fade_s: 3.0,
        };
        assert!(bad.check().is_err());
    }
}
