//! The nuScenes detection metrics, computed as the official devkit computes them
//! (`nuscenes/eval/detection`: `accumulate`, `calc_ap`, `calc_tp`, `DetectionMetrics`), so that
//! a figure here is the devkit's for the same boxes: average precision over the 0.5/1/2/4 m
//! centre-distance thresholds, the true-positive errors (translation, scale, orientation,
//! velocity, attribute) at 2 m, and the nuScenes detection score
//!
//! NDS = (5 · mAP + Σ_tp max(0, 1 − mTP)) / 10.
//!
//! One difference, said where it applies: the devkit also drops bicycles and motorcycles
//! parked in a map's bike racks; we score no map layer, and the synthetic world has no racks.

pub mod accumulate;
pub mod numpy;
pub mod scores;
pub mod truth;

pub use accumulate::{MetricData, TP_METRICS, accumulate, center_distance, scale_iou};
pub use scores::{DetectionConfig, DetectionScores, EvaluationError, evaluate};
pub use truth::{SampleTruth, TrueBox, ego_distance, filter_boxes, sample_truth, true_box};
