//! Seeded initialisation: the same seed gives the same weights, whatever else the process is
//! doing.
//!
//! Why this is not just `device.seed(s)` before `init`: burn draws from one process-wide
//! generator per backend, and its parameters are lazy, drawn at their first use. A model
//! seeded and built in one test therefore took values that depended on which other tests drew
//! random numbers in between, and on the order of its own first forward pass. Here every
//! parameter is drawn at once, in module order, under one process-wide lock taken by every
//! seeded initialisation. Random tensors elsewhere are drawn on the host from seeded
//! generators (`random_tensor`), never from burn's generator (clippy's `disallowed-methods`
//! holds that line).

use std::cell::Cell;
use std::sync::Mutex;

use bevworld_types::SplitMix64;
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;

static DRAWS: Mutex<()> = Mutex::new(());

thread_local! {
    /// Whether this thread holds `DRAWS`: a model built inside another's initialisation
    /// (a discriminator beside a generator) must not wait for itself.
    static HOLDING: Cell<bool> = const { Cell::new(false) };
}

struct Materialise;

impl ModuleVisitor for Materialise {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        // `val` runs a lazy parameter's initialiser; the value itself is not needed here.
        let _ = param.val();
    }
}

/// `build(device)` with burn's generator seeded with `seed`, every parameter drawn before it
/// returns, in module order, while no other seeded initialisation can draw.
pub fn seeded_init<M: Module>(seed: u64, device: &Device, build: impl FnOnce(&Device) -> M) -> M {
    let nested = HOLDING.with(Cell::get);
    let guard = (!nested).then(|| match DRAWS.lock() {
        Ok(guard) => guard,
        // A thread that panicked while drawing leaves nothing half-done behind: the next
        // initialisation seeds the generator afresh.
        Err(poisoned) => poisoned.into_inner(),
    });
    HOLDING.with(|h| h.set(true));
    #[allow(clippy::disallowed_methods)] // the one place that seeds burn's generator
    device.seed(seed);
    let module = build(device);
    module.visit(&mut Materialise);
    if !nested {
        HOLDING.with(|h| h.set(false));
    }
    drop(guard);
    module
}

/// Values for a tensor of `shape`, drawn on the host from `seed`: uniform in `[low, high)`, or
/// (with `normal`) Gaussian of mean `low` and standard deviation `high` by Box–Muller. For test
/// inputs and noise, so that no draw touches burn's process-wide generator.
pub fn random_values(seed: u64, count: usize, low: f64, high: f64, normal: bool) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    let mut unit = || rng.unit();
    (0..count)
        .map(|_| {
            if normal {
                let (u1, u2) = (1.0 - unit(), unit());
                let z = (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos();
                (low + high * z) as f32
            } else {
                (low + (high - low) * unit()) as f32
            }
        })
        .collect()
}

/// A tensor of `shape` with values uniform in `[low, high)`, drawn on the host from `seed`.
pub fn random_tensor<const D: usize>(
    seed: u64,
    shape: [usize; D],
    low: f64,
    high: f64,
    device: &Device,
) -> Tensor<D> {
    let count = shape.iter().product();
    Tensor::from_data(
        TensorData::new(random_values(seed, count, low, high, false), shape),
        device,
    )
}

/// A tensor of `shape` with Gaussian values of the given mean and standard deviation, drawn
/// on the host from `seed`.
pub fn random_normal<const D: usize>(
    seed: u64,
    shape: [usize; D],
    mean: f64,
    std: f64,
    device: &Device,
) -> Tensor<D> {
    let count = shape.iter().product();
    Tensor::from_data(
        TensorData::new(random_values(seed, count, mean, std, true), shape),
        device,
    )
}
