//! The sparsity prior on the voxel field's opacity: empty air, so that empty-space skipping
//! has something to skip.
//!
//! Without it nothing asks the field for zero opacity where no ray ever stops: a ray's loss is
//! the same whether the air it crosses has α = 10⁻² or 10⁻⁶, and the shipped field holds
//! α > 10⁻³ in nine of its ten voxels. The prior is Plenoxels' Cauchy sparsity loss, on α at
//! every voxel centre (what the occupancy grid reads) rather than on σ:
//!
//! `L = mean_v ln(1 + α_v / ε) / ln(1 + 1 / ε)`, with `ε` the α that skipping counts as empty.
//!
//! Its pull on a voxel's logit `s` (α = σ(s)) is `α(1 − α) / (ε + α)`: about 1 − α while
//! α ≫ ε, fading as α falls through ε, so that it empties the air down to the threshold
//! without driving every logit to −∞; a surface, which the render losses hold, pays a bounded
//! price. The normalisation puts the term in [0, 1]: 1 for a field opaque everywhere, 0 for
//! one empty everywhere.

use bevworld_tokenizer::Tokenizer;
use bevworld_tokenizer::render::VoxelField;
use bevworld_tokenizer::render::occupancy::SkipOptions;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

/// `ε`: the α at or below which a voxel is empty for empty-space skipping.
pub fn empty_alpha() -> f32 {
    SkipOptions::default().alpha_threshold
}

/// The prior over every voxel of `field`, as `[1]`.
pub fn density_sparsity(model: &Tokenizer, field: &VoxelField) -> Tensor<1> {
    let table = field.table().clone(); // [V, C_v]
    let [voxels, channels] = table.dims();
    let logits = model.alpha_logits(table.reshape([1, voxels, channels])); // [1, V]
    cauchy_of_alpha(sigmoid(logits).reshape([voxels]), empty_alpha())
}

/// `mean ln(1 + α / ε) / ln(1 + 1 / ε)` of `alpha` `[V]`, as `[1]`.
pub fn cauchy_of_alpha(alpha: Tensor<1>, epsilon: f32) -> Tensor<1> {
    let scale = (1.0 + 1.0 / f64::from(epsilon)).ln();
    alpha
        .div_scalar(epsilon)
        .log1p()
        .mean()
        .div_scalar(scale)
        .reshape([1])
}
