//! Host kernels: our own loops over a tensor's values, for the ops that burn's CPU backend runs
//! slowly (scalar transcendentals, gather-weight-sum patterns that would materialise large
//! intermediates). They run only for inference on the CPU: a tensor under autodiff keeps
//! burn's ops and their backward passes, and a GPU tensor is never copied to the host.

use burn::prelude::*;
use burn::tensor::DType;

/// The values of `tensor`, row-major, when a host kernel may replace the op: an f32 tensor on
/// the flex (CPU) device, outside autodiff. `None` otherwise, and the caller runs burn's op.
pub fn inference_values<const D: usize>(tensor: &Tensor<D>) -> Option<Vec<f32>> {
    if tensor.is_autodiff() || tensor.dtype() != DType::F32 || tensor.device() != Device::flex() {
        return None;
    }
    tensor.clone().into_data().try_into_vec::<f32>().ok()
}
