//! The integration tests of `bevworld-blocks`.
//!
//! One binary, one module per file and concern: a binary per file linked burn into each, some
//! 500 MB apiece, for the same tests.

mod activation;
mod attention_on_host;
mod blocks;
mod compare;
mod fast_math;
mod host_attention;
mod linear_on_host;
mod packed_attention;
mod reference;
mod softmax;
mod swin;
