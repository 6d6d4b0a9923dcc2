//! Evaluation metrics. Every claim about accuracy in this project rests on these.

pub mod chamfer;

pub use chamfer::{ChamferResult, Roi, chamfer, chamfer_in_roi};
