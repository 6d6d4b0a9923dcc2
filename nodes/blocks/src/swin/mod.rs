//! Swin Transformer parts (Liu et al. 2021): window attention with relative position bias,
//! shifted windows with their mask, patch merging, and the decoder's patch expanding.

pub mod attention;
pub mod backbone;
pub mod block;
pub mod host_attention;
pub mod patch;
pub mod window;

pub use backbone::{SwinBackbone, SwinConfig, run_blocks};
pub use block::{SwinBlock, SwinBlockConfig};
