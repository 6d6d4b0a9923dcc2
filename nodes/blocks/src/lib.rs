//! Network blocks shared by every model of the workspace: attention (plain, windowed, with
//! additive masks), the Swin Transformer parts, MLPs, sinusoidal embeddings, AdaLN modulation,
//! seeded initialisation, per-device tensor caches, and weights files (burnpack, and PyTorch
//! state dicts for pretrained feature networks).
//!
//! Each block is a `Config`, then `init(&device)`, then `forward`, with shapes in comments.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

pub mod activation;
pub mod adaln;
pub mod attention;
pub mod attention_on_host;
pub mod cache;
pub mod embedding;
pub mod fast_math;
pub mod host;
pub mod init;
pub mod linear_on_host;
pub mod mlp;
pub mod module_file;
pub mod swin;
pub mod torch_weights;

pub use activation::gelu;
pub use adaln::{
    AdaLnModulation, AdaLnModulationConfig, gated_residual, layer_norm, modulate,
    modulated_layer_norm,
};
pub use attention::{MASKED, MultiHeadAttention, MultiHeadAttentionConfig, causal_mask};
pub use cache::TensorCache;
pub use embedding::{sinusoidal_1d, sinusoidal_2d, timestep_embedding};
pub use init::seeded_init;
pub use mlp::{Mlp, MlpConfig};
pub use module_file::{ModuleFileError, check_file, first_non_finite, load_module, save_module};
pub use torch_weights::{TorchLoadError, load_torch_state_dict};
