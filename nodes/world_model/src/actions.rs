//! The ego actions a forecast is conditioned on, normalised with statistics of the training
//! set so that speeds (≈10 m/s) and yaw rates (≈0.3 rad/s) enter the network at one scale.

use bevworld_types::EgoAction;
use serde::{Deserialize, Serialize};

/// `EgoAction::as_features`: speed, yaw rate, dx, dy, dyaw.
pub const ACTION_FEATURES: usize = 5;

/// Per-feature mean and standard deviation over the training set's actions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionStats {
    pub mean: [f64; ACTION_FEATURES],
    pub std: [f64; ACTION_FEATURES],
    /// Actions the statistics were computed over.
    pub count: usize,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ActionStatsError {
    #[error("no actions to compute statistics over")]
    Empty,
    #[error("action {index} has a non-finite feature: {features:?}")]
    NonFinite {
        index: usize,
        features: [f32; ACTION_FEATURES],
    },
}

impl ActionStats {
    /// Mean and population standard deviation of every feature; a feature that never varies
    /// gets standard deviation 1, so it normalises to 0 rather than to infinity.
    pub fn compute<'a>(
        actions: impl IntoIterator<Item = &'a EgoAction>,
    ) -> Result<Self, ActionStatsError> {
        let mut sum = [0.0f64; ACTION_FEATURES];
        let mut squares = [0.0f64; ACTION_FEATURES];
        let mut count = 0usize;
        for (index, action) in actions.into_iter().enumerate() {
            let features = action.as_features();
            if features.iter().any(|f| !f.is_finite()) {
                return Err(ActionStatsError::NonFinite { index, features });
            }
            for (k, f) in features.iter().enumerate() {
                sum[k] += f64::from(*f);
                squares[k] += f64::from(*f) * f64::from(*f);
            }
            count += 1;
        }
        if count == 0 {
            return Err(ActionStatsError::Empty);
        }
        let n = count as f64;
        let mean = sum.map(|s| s / n);
        let mut std = [1.0; ACTION_FEATURES];
        for k in 0..ACTION_FEATURES {
            let variance = (squares[k] / n - mean[k] * mean[k]).max(0.0);
            if variance > 1e-12 {
                std[k] = variance.sqrt();
            }
        }
        Ok(Self { mean, std, count })
    }

    /// `(features − mean) / std`.
    pub fn normalise(&self, action: &EgoAction) -> [f32; ACTION_FEATURES] {
        let features = action.as_features();
        std::array::from_fn(|k| ((f64::from(features[k]) - self.mean[k]) / self.std[k]) as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn action(speed: f64, yaw_rate: f64) -> EgoAction {
        EgoAction {
            speed_mps: speed,
            yaw_rate_rps: yaw_rate,
            dx: speed * 0.5,
            dy: 0.0,
            dyaw: yaw_rate * 0.5,
            dt_s: 0.5,
        }
    }

    #[test]
    fn statistics_normalise_to_zero_mean_and_unit_spread() {
        let actions = [action(8.0, 0.2), action(10.0, -0.2), action(12.0, 0.0)];
        let stats = ActionStats::compute(&actions).unwrap();
        assert!((stats.mean[0] - 10.0).abs() < 1e-9);
        // Population deviation of {8, 10, 12}: √(8/3).
        assert!((stats.std[0] - (8.0f64 / 3.0).sqrt()).abs() < 1e-6);
        // dy never varies: deviation 1, normalised to 0.
        assert_eq!(stats.std[3], 1.0);
        let n = stats.normalise(&actions[0]);
        assert!((f64::from(n[0]) + 2.0 / (8.0f64 / 3.0).sqrt()).abs() < 1e-5);
        assert_eq!(n[3], 0.0);
    }

    #[test]
    fn empty_and_non_finite_actions_are_refused() {
        assert_eq!(
            ActionStats::compute(&[]).unwrap_err(),
            ActionStatsError::Empty
        );
        let bad = [action(1.0, 0.0), action(f64::NAN, 0.0)];
        assert!(matches!(
            ActionStats::compute(&bad),
            Err(ActionStatsError::NonFinite { index: 1, .. })
        ));
    }
}
