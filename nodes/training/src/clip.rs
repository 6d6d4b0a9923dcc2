//! Gradient clipping by the global norm over every parameter (burn clips per tensor only):
//! `g ← g · min(1, max_norm / ‖g‖)` with `‖g‖² = Σ over all parameters of Σ g²`.

use burn::module::{Module, ModuleVisitor, Param};
use burn::optim::GradientsParams;
use burn::prelude::*;

struct SquaredNorm<'a> {
    grads: &'a GradientsParams,
    total: f64,
}

impl ModuleVisitor for SquaredNorm<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(grad) = self.grads.get::<D>(param.id) {
            let squares: f32 = grad.powf_scalar(2.0).sum().into_scalar();
            self.total += f64::from(squares);
        }
    }
}

struct Scale<'a> {
    grads: &'a mut GradientsParams,
    factor: f32,
}

impl ModuleVisitor for Scale<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(grad) = self.grads.remove::<D>(param.id) {
            self.grads.register(param.id, grad.mul_scalar(self.factor));
        }
    }
}

/// The global gradient norm of `module`'s parameters.
pub fn global_norm<M: Module>(module: &M, grads: &GradientsParams) -> f64 {
    let mut visitor = SquaredNorm { grads, total: 0.0 };
    module.visit(&mut visitor);
    visitor.total.sqrt()
}

/// Scales the gradients so that their global norm is at most `max_norm`; returns the norm
/// before clipping.
pub fn clip_global_norm<M: Module>(module: &M, grads: &mut GradientsParams, max_norm: f64) -> f64 {
    let norm = global_norm(module, grads);
    if norm.is_finite() && norm > max_norm && max_norm > 0.0 {
        let mut visitor = Scale {
            grads,
            factor: (max_norm / norm) as f32,
        };
        module.visit(&mut visitor);
    }
    norm
}

/// A step's gradient norm was not finite: nothing was applied.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("the gradient norm is {0}")]
pub struct NonFiniteGradient(pub f64);

/// The end of an optimiser step, the same for every model: the micro-batches' gradients
/// summed in their order (`sum_in_order`), clipped to the global norm `max_norm`, and applied
/// at `lr`. Returns the updated model and the norm before clipping; a non-finite norm applies
/// nothing.
pub fn apply_gradients<M: Module>(
    model: M,
    optimizer: &mut burn::optim::ModuleOptimizer,
    parts: impl IntoIterator<Item = GradientsParams>,
    max_norm: f64,
    lr: f64,
) -> Result<(M, f64), NonFiniteGradient> {
    let mut grads = crate::parallel::sum_in_order(&model, parts);
    let norm = clip_global_norm(&model, &mut grads, max_norm);
    if !norm.is_finite() {
        return Err(NonFiniteGradient(norm));
    }
    Ok((optimizer.step(lr, model, grads), norm))
}
