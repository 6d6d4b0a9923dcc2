//! How the host allocator treats the memory a CPU model frees.
//!
//! A flex training step allocates and frees tensors of tens of megabytes. mimalloc, the
//! allocator of the `bevworld` binary and the benchmarks, by default hands freed memory back to
//! the kernel after 10 ms, and the next step faults it in again, zeroing every (huge) page:
//! `clear_page_erms` was 12% of a tiny training step under perf, and keeping the memory made
//! 30 steps 15% faster (33.7 s to 27.7 s) with bit-identical losses. The price is that the
//! process keeps its peak memory, a few hundred megabytes for the tiny model.

/// mimalloc's `mi_option_purge_delay` (v3 `mimalloc.h`; the Rust bindings name no constant).
const PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Tells mimalloc never to return freed memory to the kernel. For binaries whose global
/// allocator is mimalloc; with another allocator it changes nothing.
#[allow(unsafe_code)] // a C call into the allocator
pub fn keep_freed_memory() {
    // SAFETY: sets one integer option; mimalloc reads options on every purge decision.
    unsafe { libmimalloc_sys::mi_option_set(PURGE_DELAY, -1) };
}

/// mimalloc's current purge delay in milliseconds (−1: never purge).
#[allow(unsafe_code)] // a C call into the allocator
pub fn purge_delay_ms() -> i64 {
    // SAFETY: reads one integer option.
    unsafe { libmimalloc_sys::mi_option_get(PURGE_DELAY) }
}
