//! The 4-channel latent: compression of the fused BEV feature. Its per-channel statistics, the
//! contract with the world model, live in `bevworld_types::latent_stats`.

pub mod compress;

pub use compress::{LatentCompress, LatentCompressConfig};
