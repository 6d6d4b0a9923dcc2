//! A replica of a module for one worker thread of a data-parallel step: the same parameter
//! values and ids, but fresh autodiff leaves.
//!
//! Why: burn's autodiff keeps one graph per connected set of tensors. Two threads whose forward
//! passes read the same leaf tensors would have their graphs merged into one, behind one
//! mutex, and the first backward would consume the other's tape. With fresh leaves each
//! thread's graph is its own, the threads run in parallel, and the gradients they return are
//! keyed by the shared parameter ids, so they add up as if one thread had computed them.

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;

struct FreshLeaves;

impl ModuleMapper for FreshLeaves {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let (id, tensor, mapper) = param.consume();
        let tracked = tensor.is_require_grad();
        let leaf = tensor.detach();
        Param::from_mapped_value(id, if tracked { leaf.require_grad() } else { leaf }, mapper)
    }
}

/// `module` with the same parameters on fresh autodiff leaves (the tensors' data is shared,
/// not copied).
pub fn replica<M: Module>(module: &M) -> M {
    module.clone().map(&mut FreshLeaves)
}
