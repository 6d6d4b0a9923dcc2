//! Matching one class's predictions to the ground truth at one centre-distance threshold, and
//! the curves the scores are read from: the devkit's `accumulate`, step for step.
//!
//! Predictions are taken in order of falling score (ties: the later one first, as the devkit's
//! sort leaves them); each takes the nearest ground-truth box of its class in its sample that no
//! earlier prediction took, and is a true positive when that box lies closer than the
//! threshold. Precision is then read at 101 recalls from 0 to 1, and each true-positive error
//! (its running mean) at the scores those recalls are reached at.

use std::collections::{BTreeMap, HashSet};

use bevworld_types::Detection;

use super::numpy::{cummean, interp, unit_linspace};
use super::truth::TrueBox;

/// Points on a curve: recalls 0, 0.01, …, 1.
pub const CURVE_POINTS: usize = 101;

/// The errors of a true positive, in the devkit's order and names.
pub const TP_METRICS: [&str; 5] = [
    "trans_err",
    "scale_err",
    "orient_err",
    "vel_err",
    "attr_err",
];

/// One class at one threshold: precision, and each true-positive error, against recall.
#[derive(Clone, Debug, PartialEq)]
pub struct MetricData {
    pub recall: Vec<f64>,
    pub precision: Vec<f64>,
    /// The score at which each recall is reached; 0 past the highest recall reached.
    pub confidence: Vec<f64>,
    /// Per `TP_METRICS`, the running mean of the error against recall.
    pub errors: [Vec<f64>; 5],
}

impl MetricData {
    /// What a class without ground truth or without a single match gets: no precision, the
    /// worst errors.
    pub fn no_predictions() -> Self {
        Self {
            recall: unit_linspace(CURVE_POINTS),
            precision: vec![0.0; CURVE_POINTS],
            confidence: vec![0.0; CURVE_POINTS],
            errors: std::array::from_fn(|_| vec![1.0; CURVE_POINTS]),
        }
    }

    /// The last recall bin with a score: where the curve ends.
    pub fn max_recall_index(&self) -> usize {
        self.confidence.iter().rposition(|&c| c != 0.0).unwrap_or(0)
    }
}

/// Planar distance between two centres, m.
pub fn center_distance(a: &Detection, b: &Detection) -> f64 {
    (a.translation[0] - b.translation[0]).hypot(a.translation[1] - b.translation[1])
}

fn velocity_l2(truth: &Detection, pred: &Detection) -> f64 {
    (pred.velocity[0] - truth.velocity[0]).hypot(pred.velocity[1] - truth.velocity[1])
}

/// IoU of the two boxes' sizes, aligned and centred: the devkit's `scale_iou`.
pub fn scale_iou(truth: &Detection, pred: &Detection) -> f64 {
    let volume = |s: &[f64; 3]| s[0] * s[1] * s[2];
    let intersection: f64 = (0..3).map(|i| truth.size[i].min(pred.size[i])).product();
    intersection / (volume(&truth.size) + volume(&pred.size) - intersection)
}

/// The smallest angle between two headings, with `period` (2π; π for a symmetric barrier).
pub fn yaw_difference(truth: &Detection, pred: &Detection, period: f64) -> f64 {
    let mut difference =
        (truth.yaw() - pred.yaw() + period / 2.0).rem_euclid(period) - period / 2.0;
    if difference > std::f64::consts::PI {
        difference -= 2.0 * std::f64::consts::PI;
    }
    difference.abs()
}

/// 1 when the attributes agree, 0 when not, NaN when the truth has none.
fn attribute_accuracy(truth: &Detection, pred: &Detection) -> f64 {
    if truth.attribute_name.is_empty() {
        f64::NAN
    } else {
        f64::from(u8::from(truth.attribute_name == pred.attribute_name))
    }
}

/// The devkit's `accumulate` for `class` at `threshold` metres.
pub fn accumulate(
    truth: &BTreeMap<String, Vec<TrueBox>>,
    predictions: &BTreeMap<String, Vec<Detection>>,
    class: &str,
    threshold: f64,
) -> MetricData {
    let positives = truth
        .values()
        .flatten()
        .filter(|t| t.detection.detection_name == class)
        .count();
    if positives == 0 {
        return MetricData::no_predictions();
    }
    let mut ranked: Vec<&Detection> = predictions
        .values()
        .flatten()
        .filter(|p| p.detection_name == class)
        .collect();
    // sorted((score, index)) then reversed: falling scores, a tie's later box first.
    let mut order: Vec<usize> = (0..ranked.len()).collect();
    order.sort_by(|&a, &b| {
        ranked[a]
            .detection_score
            .total_cmp(&ranked[b].detection_score)
            .then(a.cmp(&b))
    });
    order.reverse();
    ranked = order.into_iter().map(|i| ranked[i]).collect();

    let period = if class == "barrier" {
        std::f64::consts::PI
    } else {
        2.0 * std::f64::consts::PI
    };
    let mut taken: HashSet<(&str, usize)> = HashSet::new();
    let (mut tp, mut fp, mut confidence) = (Vec::new(), Vec::new(), Vec::new());
    let mut matched: [Vec<f64>; 5] = Default::default();
    let mut matched_confidence = Vec::new();
    for pred in ranked {
        let mut nearest: Option<(usize, f64)> = None;
        for (index, candidate) in truth
            .get(&pred.sample_token)
            .map(Vec::as_slice)
            .unwrap_or_default()
            .iter()
            .enumerate()
        {
            if candidate.detection.detection_name != class
                || taken.contains(&(pred.sample_token.as_str(), index))
            {
                continue;
            }
            let distance = center_distance(&candidate.detection, pred);
            if nearest.is_none_or(|(_, best)| distance < best) {
                nearest = Some((index, distance));
            }
        }
        confidence.push(pred.detection_score);
        match nearest {
            Some((index, distance)) if distance < threshold => {
                taken.insert((pred.sample_token.as_str(), index));
                tp.push(1.0);
                fp.push(0.0);
                let found = &truth[&pred.sample_token][index].detection;
                matched[0].push(center_distance(found, pred));
                matched[1].push(1.0 - scale_iou(found, pred));
                matched[2].push(yaw_difference(found, pred, period));
                matched[3].push(velocity_l2(found, pred));
                matched[4].push(1.0 - attribute_accuracy(found, pred));
                matched_confidence.push(pred.detection_score);
            }
            _ => {
                tp.push(0.0);
                fp.push(1.0);
            }
        }
    }
    if matched_confidence.is_empty() {
        return MetricData::no_predictions();
    }
    let running = |values: &[f64]| -> Vec<f64> {
        values
            .iter()
            .scan(0.0, |sum, v| {
                *sum += v;
                Some(*sum)
            })
            .collect()
    };
    let (tp, fp) = (running(&tp), running(&fp));
    let precision: Vec<f64> = tp.iter().zip(&fp).map(|(t, f)| t / (t + f)).collect();
    let recall: Vec<f64> = tp.iter().map(|t| t / positives as f64).collect();
    let grid = unit_linspace(CURVE_POINTS);
    let precision = interp(&grid, &recall, &precision, precision[0], 0.0);
    let confidence = interp(&grid, &recall, &confidence, confidence[0], 0.0);
    // Each error's running mean, read at the scores the recalls are reached at (both curves
    // reversed, so that the scores rise).
    let rising_scores: Vec<f64> = confidence.iter().rev().copied().collect();
    let matched_rising: Vec<f64> = matched_confidence.iter().rev().copied().collect();
    let errors = matched.map(|values| {
        let mean: Vec<f64> = cummean(&values).into_iter().rev().collect();
        let (first, last) = (mean[0], mean[mean.len() - 1]);
        let mut read = interp(&rising_scores, &matched_rising, &mean, first, last);
        read.reverse();
        read
    });
    MetricData {
        recall: grid,
        precision,
        confidence,
        errors,
    }
}
