//! From curves to figures: each class's AP at each threshold (`calc_ap`), its true-positive
//! errors at the TP threshold (`calc_tp`), their means over classes, and NDS.

use std::collections::BTreeMap;

use bevworld_types::Detection;
use serde::{Deserialize, Serialize};

use super::accumulate::{MetricData, TP_METRICS, accumulate};
use super::truth::{SampleTruth, filter_boxes};

/// The evaluation's settings: the devkit's `detection_cvpr_2019` by default, which scores all
/// ten classes (a class a dataset lacks scores AP 0 and the worst errors, as the devkit has
/// it). `for_classes` scores a subset, which the devkit's config does not allow: figures on it
/// are ours, to be named as such beside the official ones.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionConfig {
    /// Each class scored, and how far from the ego its boxes count, m.
    pub class_range: BTreeMap<String, f64>,
    /// Centre-distance thresholds of the APs, m.
    pub dist_ths: Vec<f64>,
    /// The threshold the true-positive errors are measured at, m.
    pub dist_th_tp: f64,
    pub min_recall: f64,
    pub min_precision: f64,
    pub max_boxes_per_sample: usize,
    pub mean_ap_weight: f64,
}

impl Default for DetectionConfig {
    fn default() -> Self {
        let ranges = [
            ("car", 50.0),
            ("truck", 50.0),
            ("bus", 50.0),
            ("trailer", 50.0),
            ("construction_vehicle", 50.0),
            ("pedestrian", 40.0),
            ("motorcycle", 40.0),
            ("bicycle", 40.0),
            ("traffic_cone", 30.0),
            ("barrier", 30.0),
        ];
        Self {
            class_range: ranges.iter().map(|(c, r)| (c.to_string(), *r)).collect(),
            dist_ths: vec![0.5, 1.0, 2.0, 4.0],
            dist_th_tp: 2.0,
            min_recall: 0.1,
            min_precision: 0.1,
            max_boxes_per_sample: 500,
            mean_ap_weight: 5.0,
        }
    }
}

impl DetectionConfig {
    /// The default settings, scoring only `classes` (not a devkit configuration).
    pub fn for_classes(classes: &[&str]) -> Self {
        let mut config = Self::default();
        config
            .class_range
            .retain(|class, _| classes.contains(&class.as_str()));
        config
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum EvaluationError {
    #[error(
        "the predictions cover {predicted} samples and the truth {truth}; they must be the same samples (first difference: {example})"
    )]
    Samples {
        predicted: usize,
        truth: usize,
        example: String,
    },
    #[error("sample {sample} has {boxes} predicted boxes; at most {limit} are scored")]
    TooManyBoxes {
        sample: String,
        boxes: usize,
        limit: usize,
    },
    #[error("the config scores no class")]
    NoClasses,
}

/// Every figure of one evaluation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DetectionScores {
    /// Per class, per threshold (as written, e.g. "0.5"), the AP.
    pub label_aps: BTreeMap<String, BTreeMap<String, f64>>,
    /// Per class, the mean AP over thresholds.
    pub mean_dist_aps: BTreeMap<String, f64>,
    /// Per class, per TP metric, the error (NaN where the devkit leaves it out).
    pub label_tp_errors: BTreeMap<String, BTreeMap<String, f64>>,
    pub mean_ap: f64,
    /// Per TP metric, the mean over classes (NaN ones skipped).
    pub tp_errors: BTreeMap<String, f64>,
    /// Per TP metric, max(0, 1 − error).
    pub tp_scores: BTreeMap<String, f64>,
    pub nd_score: f64,
}

/// The devkit's `calc_ap`: mean precision above the minimum recall, less the minimum
/// precision, rescaled to [0, 1].
pub fn average_precision(data: &MetricData, min_recall: f64, min_precision: f64) -> f64 {
    let first = (100.0 * min_recall).round() as usize + 1;
    let clipped: Vec<f64> = data.precision[first.min(data.precision.len())..]
        .iter()
        .map(|p| (p - min_precision).max(0.0))
        .collect();
    if clipped.is_empty() {
        return 0.0;
    }
    clipped.iter().sum::<f64>() / clipped.len() as f64 / (1.0 - min_precision)
}

/// The devkit's `calc_tp`: the mean of an error's curve from the minimum recall to the
/// highest recall reached; 1 (the worst) when that is below the minimum.
pub fn true_positive_error(data: &MetricData, min_recall: f64, metric: usize) -> f64 {
    let first = (100.0 * min_recall).round() as usize + 1;
    let last = data.max_recall_index();
    if last < first {
        return 1.0;
    }
    let values = &data.errors[metric][first..=last];
    values.iter().sum::<f64>() / values.len() as f64
}

/// Whether the devkit leaves this error out for this class: a cone has no heading, speed or
/// attribute worth scoring, a barrier no speed or attribute.
fn left_out(class: &str, metric: &str) -> bool {
    match class {
        "traffic_cone" => matches!(metric, "attr_err" | "vel_err" | "orient_err"),
        "barrier" => matches!(metric, "attr_err" | "vel_err"),
        _ => false,
    }
}

/// Scores `predictions` against `truth` (the same samples) as the devkit does.
pub fn evaluate(
    config: &DetectionConfig,
    truth: &BTreeMap<String, SampleTruth>,
    predictions: &BTreeMap<String, Vec<Detection>>,
) -> Result<DetectionScores, EvaluationError> {
    if config.class_range.is_empty() {
        return Err(EvaluationError::NoClasses);
    }
    if let Some(example) = truth
        .keys()
        .find(|s| !predictions.contains_key(*s))
        .or_else(|| predictions.keys().find(|s| !truth.contains_key(*s)))
    {
        return Err(EvaluationError::Samples {
            predicted: predictions.len(),
            truth: truth.len(),
            example: example.clone(),
        });
    }
    if let Some((sample, boxes)) = predictions
        .iter()
        .find(|(_, boxes)| boxes.len() > config.max_boxes_per_sample)
    {
        return Err(EvaluationError::TooManyBoxes {
            sample: sample.clone(),
            boxes: boxes.len(),
            limit: config.max_boxes_per_sample,
        });
    }
    let (truth, predictions) = filter_boxes(truth, predictions, &config.class_range);
    let mut label_aps = BTreeMap::new();
    let mut label_tp_errors = BTreeMap::new();
    for class in config.class_range.keys() {
        let aps: BTreeMap<String, f64> = config
            .dist_ths
            .iter()
            .map(|&threshold| {
                let data = accumulate(&truth, &predictions, class, threshold);
                (
                    threshold.to_string(),
                    average_precision(&data, config.min_recall, config.min_precision),
                )
            })
            .collect();
        label_aps.insert(class.clone(), aps);
        let data = accumulate(&truth, &predictions, class, config.dist_th_tp);
        let errors: BTreeMap<String, f64> = TP_METRICS
            .iter()
            .enumerate()
            .map(|(index, metric)| {
                let error = if left_out(class, metric) {
                    f64::NAN
                } else {
                    true_positive_error(&data, config.min_recall, index)
                };
                (metric.to_string(), error)
            })
            .collect();
        label_tp_errors.insert(class.clone(), errors);
    }
    let mean = |values: &[f64]| values.iter().sum::<f64>() / values.len() as f64;
    let mean_dist_aps: BTreeMap<String, f64> = label_aps
        .iter()
        .map(|(class, aps)| {
            (
                class.clone(),
                mean(&aps.values().copied().collect::<Vec<_>>()),
            )
        })
        .collect();
    let mean_ap = mean(&mean_dist_aps.values().copied().collect::<Vec<_>>());
    let mut tp_errors = BTreeMap::new();
    let mut tp_scores = BTreeMap::new();
    for metric in TP_METRICS {
        let known: Vec<f64> = label_tp_errors
            .values()
            .map(|errors| errors[metric])
            .filter(|e| !e.is_nan())
            .collect();
        // np.nanmean of nothing is NaN, and Python's max(0.0, nan) is 0.
        let error = if known.is_empty() {
            f64::NAN
        } else {
            mean(&known)
        };
        tp_errors.insert(metric.to_string(), error);
        let score = 1.0 - error;
        tp_scores.insert(metric.to_string(), if score > 0.0 { score } else { 0.0 });
    }
    let nd_score = (config.mean_ap_weight * mean_ap + tp_scores.values().sum::<f64>())
        / (config.mean_ap_weight + tp_scores.len() as f64);
    Ok(DetectionScores {
        label_aps,
        mean_dist_aps,
        label_tp_errors,
        mean_ap,
        tp_errors,
        tp_scores,
        nd_score,
    })
}
