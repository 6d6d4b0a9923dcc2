//! An exponential moving average of a model's parameters, the weights a run ships when
//! `ema_decay` is set.
//!
//! Why: a run that stops while its learning rate is still high (half way down a longer cosine)
//! ends on a noisy iterate; the mean of its last few hundred iterates sits nearer the basin's
//! floor. The mean of two checkpoints 300 steps apart at 53.5% of the peak rate already read
//! 0.036 dB and 0.012 m² better than the later one alone.
//!
//! Update after optimiser step `t` (counted from 1): `ema ← d·ema + (1 − d)·θ` with
//! `d = min(decay, (1 + t) / (10 + t))`, so that the first steps, whose iterates the average
//! would otherwise keep for thousands of steps, weigh little (timm's and diffusers' warm-up).

use std::collections::VecDeque;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;

/// The decay applied after step `step` (counted from 1) for a configured `decay`.
pub fn effective_decay(decay: f64, step: usize) -> f64 {
    let t = step as f64;
    decay.min((1.0 + t) / (10.0 + t))
}

/// Every float parameter of a module, flattened, in visiting order. Parameters are paired by
/// position, not by id: a module loaded from a checkpoint is built afresh, and the pairing
/// must not depend on how a load treats ids.
struct Collect {
    values: VecDeque<Tensor<1>>,
}

impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        self.values.push_back(param.val().inner().flatten(0, D - 1));
    }
}

/// Moves each parameter of the average toward the model's parameter at the same position.
struct Blend {
    model: VecDeque<Tensor<1>>,
    decay: f64,
    mismatched: usize,
}

impl ModuleMapper for Blend {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, average, mapper) = param.consume();
        let shape = average.shape();
        let blended = match self.model.pop_front() {
            Some(current) if current.shape().num_elements() == shape.num_elements() => {
                let current: Tensor<D> = current.reshape(shape);
                average
                    .mul_scalar(self.decay)
                    .add(current.mul_scalar(1.0 - self.decay))
            }
            _ => {
                self.mismatched += 1;
                average
            }
        };
        Param::from_mapped_value(id, blended, mapper)
    }
}

#[derive(Debug, thiserror::Error)]
#[error("the weight average and the model differ in {count} parameters (not the same module)")]
pub struct MismatchedModules {
    pub count: usize,
}

/// `average` moved one step toward `model` (an autodiff module; its values are read without
/// their graph) with the decay for step `step`. `average` lives on the inner device.
pub fn update<M: Module>(
    average: M,
    model: &M,
    decay: f64,
    step: usize,
) -> Result<M, MismatchedModules> {
    let mut collect = Collect {
        values: VecDeque::new(),
    };
    model.visit(&mut collect);
    let mut blend = Blend {
        model: collect.values,
        decay: effective_decay(decay, step),
        mismatched: 0,
    };
    let average = average.map(&mut blend);
    let count = blend.mismatched + blend.model.len();
    if count > 0 {
        return Err(MismatchedModules { count });
    }
    Ok(average)
}
