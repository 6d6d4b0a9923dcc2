//! Constant tensors a module needs on every forward pass (index tables, masks), built once per
//! device and key instead of being rebuilt and uploaded every time.
//!
//! Why a cache and not a module field: a tensor field would be built on the device the module
//! was made on, while the same module runs both on an autodiff device (training) and its inner
//! device (validation, `valid()`); the cache builds each device's copy on first use. Clones of
//! a module (training replicas) share one cache.

use std::sync::{Arc, Mutex};

use burn::prelude::*;
use burn::tensor::kind::Basic as BasicOps;

/// Tensors by key and device, shared by the clones of the module that holds it.
pub struct TensorCache<Key, const D: usize, Kind: BasicOps = Float> {
    entries: Arc<Mutex<Vec<Entry<Key, D, Kind>>>>,
}

struct Entry<Key, const D: usize, Kind: BasicOps> {
    key: Key,
    device: Device,
    autodiff: bool,
    tensor: Tensor<D, Kind>,
}

impl<Key, const D: usize, Kind: BasicOps> Clone for TensorCache<Key, D, Kind> {
    fn clone(&self) -> Self {
        Self {
            entries: Arc::clone(&self.entries),
        }
    }
}

impl<Key, const D: usize, Kind: BasicOps> Default for TensorCache<Key, D, Kind> {
    fn default() -> Self {
        Self {
            entries: Arc::new(Mutex::new(Vec::new())),
        }
    }
}

impl<Key, const D: usize, Kind: BasicOps> std::fmt::Debug for TensorCache<Key, D, Kind> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let held = self.entries.lock().map_or(0, |entries| entries.len());
        write!(f, "TensorCache({held} tensors)")
    }
}

impl<Key: PartialEq, const D: usize, Kind: BasicOps> TensorCache<Key, D, Kind> {
    /// The tensor for `key` on `device`, built by `build` on first use.
    pub fn get_or_build(
        &self,
        key: Key,
        device: &Device,
        build: impl FnOnce() -> Tensor<D, Kind>,
    ) -> Tensor<D, Kind> {
        let autodiff = device.is_autodiff();
        // A poisoned lock only means another thread panicked while building; the entries
        // that made it in are whole, so keep using them.
        let mut entries = match self.entries.lock() {
            Ok(entries) => entries,
            Err(poisoned) => poisoned.into_inner(),
        };
        if let Some(entry) = entries
            .iter()
            .find(|e| e.key == key && e.device == *device && e.autodiff == autodiff)
        {
            return entry.tensor.clone();
        }
        let tensor = build();
        entries.push(Entry {
            key,
            device: device.clone(),
            autodiff,
            tensor: tensor.clone(),
        });
        tensor
    }

    /// How many tensors are held, for tests.
    pub fn len(&self) -> usize {
        self.entries.lock().map_or(0, |entries| entries.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}
