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
    let factor = clip_factor(norm, max_norm);
    if factor < 1.0 {
        module.visit(&mut Scale { grads, factor });
    }
    norm
}

/// A step's gradient norm was not finite: nothing was applied.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("the gradient norm is {0}")]
pub struct NonFiniteGradient(pub f64);

/// The factor that brings a gradient of norm `norm` to at most `max_norm` (1 when it is within
/// it, or when clipping is off).
fn clip_factor(norm: f64, max_norm: f64) -> f32 {
    if norm.is_finite() && norm > max_norm && max_norm > 0.0 {
        (max_norm / norm) as f32
    } else {
        1.0
    }
}

/// A part of a model with its own optimiser and learning rate, and the gradients of its
/// parameters from each micro-batch, in order.
pub struct Part<'a, M: Module> {
    pub model: M,
    pub optimizer: &'a mut burn::optim::ModuleOptimizer,
    pub grads: Vec<GradientsParams>,
    pub lr: f64,
}

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

/// `apply_gradients` for a model trained as two parts, each with its optimiser and rate (a
/// pretrained encoder fine-tuned at a fraction of its head's rate): the global norm is taken
/// over both parts' gradients together, and both are clipped by the same factor, as one
/// model's would be. Returns both parts and the norm before clipping.
pub fn apply_gradients_in_two<A: Module, B: Module>(
    first: Part<'_, A>,
    second: Part<'_, B>,
    max_norm: f64,
) -> Result<(A, B, f64), NonFiniteGradient> {
    let mut grads_a = crate::parallel::sum_in_order(&first.model, first.grads);
    let mut grads_b = crate::parallel::sum_in_order(&second.model, second.grads);
    let (norm_a, norm_b) = (
        global_norm(&first.model, &grads_a),
        global_norm(&second.model, &grads_b),
    );
    let norm = (norm_a * norm_a + norm_b * norm_b).sqrt();
    if !norm.is_finite() {
        return Err(NonFiniteGradient(norm));
    }
    let factor = clip_factor(norm, max_norm);
    if factor < 1.0 {
        first.model.visit(&mut Scale {
            grads: &mut grads_a,
            factor,
        });
        second.model.visit(&mut Scale {
            grads: &mut grads_b,
            factor,
        });
    }
    let a = first.optimizer.step(first.lr, first.model, grads_a);
    let b = second.optimizer.step(second.lr, second.model, grads_b);
    Ok((a, b, norm))
}
