//! Data-parallel steps on one machine: each item (a frame of a step, a validation frame) runs
//! on a worker thread with its own replica of the model, and the results come back in item
//! order, so that the gradients they sum to, and so the whole run, do not depend on the
//! thread count.
//!
//! Why replicas: burn's autodiff keeps one graph per connected set of tensors. Two threads
//! whose forward passes read the same leaf tensors would have their graphs merged into one,
//! behind one mutex, and the first backward would consume the other's tape. With fresh leaves
//! each thread's graph is its own, the threads run in parallel, and the gradients they return
//! are keyed by the shared parameter ids, so they add up as if one thread had computed them.
//!
//! How the cores are shared: the items are the parallelism. Each worker runs its items inside
//! a rayon pool of one thread, so the tensor ops under it (burn's CPU backend fans out to
//! rayon) run serially on that worker instead of competing with the other workers for the
//! global pool. Two frames on two cores never become four busy threads, and an item's result
//! cannot depend on how many threads an op was split over, so the run does not depend on the
//! thread count. Inference outside this function uses the global pool, sized to the cores.

use std::panic::{AssertUnwindSafe, catch_unwind};

use burn::module::{Module, ModuleMapper, Param};
use burn::optim::{GradientsAccumulator, GradientsParams};
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

/// A worker panicked: the step or validation it belonged to did not happen.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("item {item} panicked on a worker thread: {message}")]
pub struct WorkerPanicked {
    pub item: usize,
    pub message: String,
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

/// `f` of every item, on up to `threads` scoped threads (item `i` on thread `i mod threads`),
/// returned in item order. `prepare` runs on the calling thread once per thread and gives
/// that thread its own state (a model replica). A panic in `f` is caught and returned as the
/// error of the first item that panicked, with one thread as with many.
pub fn parallel_map<T: Sync, S: Send, R: Send>(
    items: &[T],
    threads: usize,
    prepare: impl Fn() -> S,
    f: impl Fn(&S, &T) -> R + Sync,
) -> Result<Vec<R>, WorkerPanicked> {
    let threads = threads.clamp(1, items.len().max(1));
    let run = |state: &S, item: usize, value: &T| {
        catch_unwind(AssertUnwindSafe(|| f(state, value))).map_err(|payload| WorkerPanicked {
            item,
            message: panic_message(payload.as_ref()),
        })
    };
    let run = &run;
    if threads == 1 {
        let state = prepare();
        return serial_ops(move || {
            items
                .iter()
                .enumerate()
                .map(|(i, item)| run(&state, i, item))
                .collect()
        });
    }
    let mut slots: Vec<Option<Result<R, WorkerPanicked>>> =
        std::iter::repeat_with(|| None).take(items.len()).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads)
            .map(|worker| {
                let state = prepare();
                scope.spawn(move || {
                    serial_ops(move || {
                        items
                            .iter()
                            .enumerate()
                            .skip(worker)
                            .step_by(threads)
                            .map(|(i, item)| (i, run(&state, i, item)))
                            .collect::<Vec<_>>()
                    })
                })
            })
            .collect();
        for handle in handles {
            // `run` catches every panic of `f`; a worker can only fail outside it, and then
            // its items stay empty and are reported below as never finished.
            if let Ok(results) = handle.join() {
                for (i, result) in results {
                    slots[i] = Some(result);
                }
            }
        }
    });
    slots
        .into_iter()
        .enumerate()
        .map(|(item, slot)| {
            slot.unwrap_or_else(|| {
                Err(WorkerPanicked {
                    item,
                    message: "its worker thread failed before finishing it".into(),
                })
            })
        })
        .collect()
}

/// Runs `work` in a rayon pool of one thread, so that the parallel loops of the tensor ops
/// under it run serially. The pool lives for this call only (its thread ends with it); a
/// thread costs microseconds against an item's milliseconds. If the system refuses the
/// thread, `work` runs here as it is, which changes its speed, not its result.
fn serial_ops<R: Send>(work: impl FnOnce() -> R + Send) -> R {
    match rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .thread_name(|_| "bevworld-item".into())
        .build()
    {
        Ok(pool) => pool.install(work),
        Err(_) => work(),
    }
}

/// The gradients of every item summed in item order (floating-point addition is not
/// associative, so the order is fixed rather than left to whichever thread finished first).
pub fn sum_in_order<M: Module>(
    model: &M,
    parts: impl IntoIterator<Item = GradientsParams>,
) -> GradientsParams {
    let mut accumulator = GradientsAccumulator::<M>::new();
    for part in parts {
        accumulator.accumulate(model, part);
    }
    accumulator.grads()
}
