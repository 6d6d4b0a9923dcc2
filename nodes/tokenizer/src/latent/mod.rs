//! The 4-channel latent: compression of the fused BEV feature, and the per-channel statistics
//! the world model standardises with.

pub mod compress;
pub mod stats;
pub mod stats_file;

pub use compress::{LatentCompress, LatentCompressConfig};
pub use stats::{LatentStats, LatentStatsAccumulator};
pub use stats_file::{LatentStatsFile, StatsFileError, stats_path_for};
