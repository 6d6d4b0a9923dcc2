//! Chooses the Burn device the models run on, and measures what it can do.
//!
//! `BURN_DEVICE=flex|wgpu|cuda` selects one; unset means `flex`, the pure-Rust CPU backend,
//! since tests and CPU training must not pick up a slow software GPU adapter by accident.
//! Burn's own `Device::default()` panics on an unknown value; this reports an error instead.

// Libraries return errors; a panic belongs to a broken invariant, said with `expect`.
#![cfg_attr(not(test), warn(clippy::unwrap_used))]

mod cpu;
mod host_memory;

pub use cpu::{cpu_model, simd_features};
pub use host_memory::{keep_freed_memory, purge_delay_ms};

use std::time::Instant;

use burn::prelude::*;
use thiserror::Error;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendKind {
    Flex,
    Wgpu,
    Cuda,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Flex => "flex",
            BackendKind::Wgpu => "wgpu",
            BackendKind::Cuda => "cuda",
        }
    }
}

#[derive(Debug, Error)]
pub enum DeviceError {
    #[error("BURN_DEVICE='{0}' is not a known backend (accepted: flex, wgpu, cuda)")]
    Unknown(String),
    #[error(
        "BURN_DEVICE=cuda, but this build has no CUDA support (rebuild with `--features cuda`)"
    )]
    CudaNotBuilt,
    #[error("the {backend} device failed: {message}")]
    Failed {
        backend: &'static str,
        message: String,
    },
}

/// Parses a backend name as `BURN_DEVICE` takes it.
pub fn parse_backend(name: &str) -> Result<BackendKind, DeviceError> {
    match name.trim().to_ascii_lowercase().as_str() {
        "" | "flex" | "cpu" => Ok(BackendKind::Flex),
        "wgpu" => Ok(BackendKind::Wgpu),
        "cuda" => Ok(BackendKind::Cuda),
        other => Err(DeviceError::Unknown(other.to_string())),
    }
}

/// The device for a backend.
pub fn device_for(kind: BackendKind) -> Result<Device, DeviceError> {
    match kind {
        BackendKind::Flex => Ok(Device::flex()),
        BackendKind::Wgpu => Ok(Device::wgpu(DeviceKind::DefaultDevice)),
        BackendKind::Cuda => cuda_device(),
    }
}

#[cfg(feature = "cuda")]
fn cuda_device() -> Result<Device, DeviceError> {
    Ok(Device::cuda(0))
}

#[cfg(not(feature = "cuda"))]
fn cuda_device() -> Result<Device, DeviceError> {
    Err(DeviceError::CudaNotBuilt)
}

/// The device named by `BURN_DEVICE` (default flex).
pub fn from_env() -> Result<(BackendKind, Device), DeviceError> {
    let kind = parse_backend(&std::env::var("BURN_DEVICE").unwrap_or_default())?;
    Ok((kind, device_for(kind)?))
}

/// Measured dense matmul rate on a device, in GFLOP/s: the best of `reps` timed `n x n` products
/// after one warm-up. The yardstick for "achieved GFLOP/s as a fraction of the machine's rate".
pub fn matmul_gflops(device: &Device, n: usize, reps: usize) -> Result<f64, DeviceError> {
    // Any finite values time the same; a ramp keeps the probe off burn's process-wide random
    // generator, which seeded model initialisation owns.
    let ramp = |offset: f32| {
        let values: Vec<f32> = (0..n * n)
            .map(|i| ((i % 97) as f32 - 48.0 + offset) / 48.0)
            .collect();
        Tensor::<2>::from_data(TensorData::new(values, [n, n]), device)
    };
    let (a, b) = (ramp(0.0), ramp(0.5));
    let sync = |t: Tensor<2>| -> Result<(), DeviceError> {
        // Reading one value back waits for the product on asynchronous backends.
        t.slice([0..1, 0..1])
            .into_data()
            .try_to_vec::<f32>()
            .map(|_| ())
            .map_err(|error| DeviceError::Failed {
                backend: "matmul",
                message: format!("{error:?}"),
            })
    };
    sync(a.clone().matmul(b.clone()))?;
    let mut best = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let started = Instant::now();
        sync(a.clone().matmul(b.clone()))?;
        best = best.min(started.elapsed().as_secs_f64());
    }
    let flops = 2.0 * (n as f64).powi(3);
    Ok(flops / best / 1e9)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backend_names_parse_and_unknown_is_an_error() {
        assert_eq!(parse_backend("").unwrap(), BackendKind::Flex);
        assert_eq!(parse_backend("WGPU").unwrap(), BackendKind::Wgpu);
        let error = parse_backend("tpu").unwrap_err().to_string();
        assert!(error.contains("'tpu'") && error.contains("flex, wgpu, cuda"));
    }

    #[test]
    fn flex_matmul_is_correct_and_measurable() {
        let device = Device::flex();
        let a = Tensor::<2>::from_floats([[1.0, 2.0], [3.0, 4.0]], &device);
        let b = Tensor::<2>::from_floats([[5.0, 6.0], [7.0, 8.0]], &device);
        let product = a.matmul(b).into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(product, vec![19.0, 22.0, 43.0, 50.0]);
        assert!(matmul_gflops(&device, 64, 2).unwrap() > 0.0);
    }
}
