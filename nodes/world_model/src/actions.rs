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
    /// The smallest and largest value of each feature in the training set: what the model has
    /// seen. Absent in statistics written before it was recorded.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub range: Option<ActionRange>,
}

/// Per-feature minimum and maximum.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionRange {
    pub min: [f64; ACTION_FEATURES],
    pub max: [f64; ACTION_FEATURES],
}

/// How far past the training range, in standard deviations of the feature, an action may go
/// before it counts as outside: a forecast a little faster than any in training is still the
/// model's to make.
pub const RANGE_MARGIN_STD: f64 = 0.25;

/// Without a recorded range: how many standard deviations from the mean count as outside.
pub const OUTSIDE_STD: f64 = 4.0;

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
    /// Whether `other` is the same statistics, up to the last bits that writing them to the
    /// weights' JSON and reading them back may change (serde_json's reading of a float can
    /// land one unit in the last place off the value written).
    pub fn matches(&self, other: &ActionStats) -> bool {
        let close = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-12 * x.abs().max(y.abs()).max(1e-300))
        };
        let ranges = match (&self.range, &other.range) {
            (Some(a), Some(b)) => close(&a.min, &b.min) && close(&a.max, &b.max),
            (None, None) => true,
            _ => false,
        };
        self.count == other.count
            && close(&self.mean, &other.mean)
            && close(&self.std, &other.std)
            && ranges
    }

    /// Mean and population standard deviation of every feature; a feature that never varies
    /// gets standard deviation 1, so it normalises to 0 rather than to infinity.
    pub fn compute<'a>(
        actions: impl IntoIterator<Item = &'a EgoAction>,
    ) -> Result<Self, ActionStatsError> {
        let mut sum = [0.0f64; ACTION_FEATURES];
        let mut squares = [0.0f64; ACTION_FEATURES];
        let mut min = [f64::INFINITY; ACTION_FEATURES];
        let mut max = [f64::NEG_INFINITY; ACTION_FEATURES];
        let mut count = 0usize;
        for (index, action) in actions.into_iter().enumerate() {
            let features = action.as_features();
            if features.iter().any(|f| !f.is_finite()) {
                return Err(ActionStatsError::NonFinite { index, features });
            }
            for (k, f) in features.iter().enumerate() {
                let f = f64::from(*f);
                sum[k] += f;
                squares[k] += f * f;
                min[k] = min[k].min(f);
                max[k] = max[k].max(f);
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
        Ok(Self {
            mean,
            std,
            count,
            range: Some(ActionRange { min, max }),
        })
    }

    /// Refuses statistics that cannot normalise an action: a mean that is not finite, a
    /// spread that is not a finite number > 0 (a division by zero, or every action's sign
    /// flipped), none counted, or a range that is not finite or runs backwards. Returns the
    /// field at fault (`std[2]`) and why.
    pub fn check(&self) -> Result<(), (String, String)> {
        if self.count == 0 {
            return Err(("count".into(), "0: statistics of no actions".into()));
        }
        for k in 0..ACTION_FEATURES {
            let (mean, std) = (self.mean[k], self.std[k]);
            if !mean.is_finite() {
                return Err((format!("mean[{k}]"), format!("{mean} is not finite")));
            }
            if !(std.is_finite() && std > 0.0) {
                return Err((
                    format!("std[{k}]"),
                    format!("{std} is not a finite number > 0: actions would be divided by it"),
                ));
            }
        }
        if let Some(range) = &self.range {
            for k in 0..ACTION_FEATURES {
                let (min, max) = (range.min[k], range.max[k]);
                if !(min.is_finite() && max.is_finite() && min <= max) {
                    return Err((
                        format!("range[{k}]"),
                        format!("[{min}, {max}] is not a finite range with min <= max"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// Whether `action` lies outside what training saw: past the training range in any feature
    /// by more than `RANGE_MARGIN_STD` of its spread, or, for statistics without a recorded
    /// range, more than `OUTSIDE_STD` standard deviations from the mean. The model still
    /// forecasts it (finite, from the same network), but its output is an extrapolation.
    pub fn outside_training(&self, action: &EgoAction) -> bool {
        let features = action.as_features();
        (0..ACTION_FEATURES).any(|k| {
            let value = f64::from(features[k]);
            match &self.range {
                Some(range) => {
                    let margin = RANGE_MARGIN_STD * self.std[k];
                    !(value >= range.min[k] - margin && value <= range.max[k] + margin)
                }
                None => !((value - self.mean[k]).abs() <= OUTSIDE_STD * self.std[k]),
            }
        })
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
    fn statistics_match_across_a_last_bit_but_not_across_other_data() {
        let actions = [action(8.0, 0.2), action(10.0, -0.2), action(12.0, 0.0)];
        let stats = ActionStats::compute(&actions).unwrap();
        // What serde_json read back from the shipped weights: 3.6262073335357203 written,
        // 3.62620733353572 read, one unit in the last place apart.
        let mut read_back = stats.clone();
        read_back.mean[2] = f64::from_bits(read_back.mean[2].to_bits() + 1);
        assert_ne!(read_back, stats);
        assert!(read_back.matches(&stats) && stats.matches(&read_back));
        let mut other = stats.clone();
        other.mean[0] += 1e-6;
        assert!(!other.matches(&stats), "other actions");
        let fewer = ActionStats::compute(&actions[..2]).unwrap();
        assert!(!fewer.matches(&stats));
        let mut unranged = stats.clone();
        unranged.range = None;
        assert!(!unranged.matches(&stats));
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
    fn actions_past_the_training_range_are_outside() {
        let actions = [action(8.0, 0.2), action(10.0, -0.2), action(12.0, 0.0)];
        let stats = ActionStats::compute(&actions).unwrap();
        let range = stats.range.clone().unwrap();
        assert_eq!((range.min[0], range.max[0]), (8.0, 12.0));
        assert!(!stats.outside_training(&action(10.0, 0.1)));
        // Speed spread √(8/3) ≈ 1.63 m/s: a margin of 0.41 m/s past 12.
        assert!(!stats.outside_training(&action(12.3, 0.0)));
        assert!(stats.outside_training(&action(12.5, 0.0)));
        assert!(stats.outside_training(&action(0.0, 0.0)), "standing still");
        assert!(stats.outside_training(&action(-3.0, 0.0)), "reversing");
        assert!(stats.outside_training(&action(10.0, 1.0)), "1 rad/s");
        assert!(
            stats.outside_training(&action(f64::NAN, 0.0)),
            "NaN is never inside"
        );
        // Without a recorded range: four standard deviations.
        let old = ActionStats {
            range: None,
            ..stats
        };
        assert!(!old.outside_training(&action(12.5, 0.0)));
        assert!(old.outside_training(&action(30.0, 0.0)));
    }

    #[test]
    fn statistics_that_cannot_normalise_are_refused_naming_the_field() {
        let actions = [action(8.0, 0.2), action(10.0, -0.2), action(12.0, 0.0)];
        let good = ActionStats::compute(&actions).unwrap();
        assert_eq!(good.check(), Ok(()));
        for (field, broken) in [
            ("std[0]", {
                let mut s = good.clone();
                s.std[0] = 0.0;
                s
            }),
            ("std[1]", {
                let mut s = good.clone();
                s.std[1] = -0.2;
                s
            }),
            ("mean[4]", {
                let mut s = good.clone();
                s.mean[4] = f64::NAN;
                s
            }),
            (
                "count",
                ActionStats {
                    count: 0,
                    ..good.clone()
                },
            ),
            ("range[0]", {
                let mut s = good.clone();
                if let Some(r) = s.range.as_mut() {
                    r.min[0] = 20.0;
                }
                s
            }),
        ] {
            let (found, message) = broken.check().unwrap_err();
            assert_eq!(found, field, "{message}");
        }
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
