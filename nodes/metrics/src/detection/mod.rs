//! The nuScenes detection metrics, computed as the official devkit computes them
//! (`nuscenes/eval/detection`: `accumulate`, `calc_ap`, `calc_tp`, `DetectionMetrics`), so that
//! a figure here is the devkit's for the same boxes: average precision over the 0.5/1/2/4 m
//! centre-distance thresholds, the true-positive errors (translation, scale, orientation,
//! velocity, attribute) at 2 m, and the nuScenes detection score
//!
//! NDS = (5 · mAP + Σ_tp max(0, 1 − mTP)) / 10.
//!
//! The filters are the devkit's: each class's range from the ego, true boxes without a
//! return, and cycles parked in an annotated bicycle rack.

pub mod accumulate;
pub mod numpy;
pub mod scores;
pub mod truth;

pub use accumulate::{MetricData, TP_METRICS, accumulate, center_distance, scale_iou};
pub use scores::{DetectionConfig, DetectionScores, EvaluationError, evaluate};
pub use truth::{SampleTruth, TrueBox, ego_distance, filter_boxes, sample_truth, true_box};
