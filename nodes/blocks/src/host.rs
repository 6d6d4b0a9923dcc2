//! Host kernels: our own loops over a tensor's values, for the ops that burn's CPU backend runs
//! slowly (scalar transcendentals, gather-weight-sum patterns that would materialise large
//! intermediates). They run only for inference on the CPU: a tensor under autodiff keeps
//! burn's ops and their backward passes, and a GPU tensor is never copied to the host.

use burn::prelude::*;
use burn::tensor::DType;

/// Whether a host kernel may replace burn's op on `tensor`: an f32 tensor on the flex (CPU)
/// device, outside autodiff.
pub fn runs_on_host<const D: usize>(tensor: &Tensor<D>) -> bool {
    !tensor.is_autodiff() && tensor.dtype() == DType::F32 && tensor.device() == Device::flex()
}

/// The values of `tensor`, row-major, when a host kernel may replace the op: an f32 tensor on
/// the flex (CPU) device, outside autodiff. `None` otherwise, and the caller runs burn's op.
pub fn inference_values<const D: usize>(tensor: &Tensor<D>) -> Option<Vec<f32>> {
    if !runs_on_host(tensor) {
        return None;
    }
    tensor.clone().into_data().try_into_vec::<f32>().ok()
}

/// `inference_values` of a tensor the caller gives up, so that its buffer can be moved out
/// rather than copied (a tensor still shared must be copied); the tensor back when a host
/// kernel may not replace the op.
// The tensor comes back by value to run burn's op: boxing it would allocate on every call.
#[allow(clippy::result_large_err)]
pub fn into_inference_values<const D: usize>(tensor: Tensor<D>) -> Result<Vec<f32>, Tensor<D>> {
    if !runs_on_host(&tensor) {
        return Err(tensor);
    }
    // The dtype is checked above; reading f32 data as f32 has no other way to fail.
    Ok(tensor
        .into_data()
        .try_into_vec::<f32>()
        .expect("an f32 tensor's data reads as f32"))
}

/// `into_inference_values` of a tensor the caller has held to `runs_on_host`.
///
/// # Panics
/// When `tensor` is not an f32 CPU inference tensor: check `runs_on_host` first.
pub fn checked_values<const D: usize>(tensor: Tensor<D>) -> Vec<f32> {
    into_inference_values(tensor)
        .unwrap_or_else(|_| panic!("checked by runs_on_host: an f32 CPU inference tensor"))
}

/// Runs `kernel` compiled for the widest vector instructions this CPU has (AVX-512, AVX2 + FMA,
/// NEON), detected at run time: the binary is built for the baseline x86-64 (SSE2), where our
/// branch-free math (`fast_math`) vectorises only 4 lanes wide and without FMA.
///
/// The kernel is a `macerator::WithSimd` whose `with_simd` is `#[inline(always)]`, and every
/// function its loop calls is `#[inline(always)]` too: only code inlined into the dispatched
/// function is compiled with the wider instructions (a closure would stay a separate function,
/// built for the baseline). Results do not depend on the instructions chosen beyond the
/// rounding of fused multiply-adds.
#[inline(always)]
pub fn vectorized<K: macerator::WithSimd>(kernel: K) -> K::Output {
    macerator::AutoArch::new().dispatch(kernel)
}

/// The vector instructions `vectorized` dispatches to on this CPU, by name: `avx512-fp16`,
/// `avx512` (x86-64-v4), `avx2+fma` (v3), `sse4.2` (v2), `neon`, or `scalar`. A kernel that
/// runs scalar on a CPU with wide vectors is several times slower; a test holds this level to
/// what the CPU reports.
pub fn dispatch_level() -> &'static str {
    let arch = macerator::Arch::detect();
    let name = format!("{arch:?}");
    match name.as_str() {
        "V4FP16" => "avx512-fp16",
        "V4" => "avx512",
        "V3" => "avx2+fma",
        "V2" => "sse4.2",
        "Scalar" => "scalar",
        _ if name.to_ascii_lowercase().contains("neon") => "neon",
        _ => "other",
    }
}

/// `values[i] = f(values[i])` for every value, as one vectorised loop: `f` must be an
/// `#[inline(always)]` function (a function item, not a pointer, so that the call is static)
/// of branch-free arithmetic (`fast_math`).
pub fn map_in_place<F: Fn(f32) -> f32>(values: &mut [f32], f: F) {
    struct Map<'a, F> {
        values: &'a mut [f32],
        f: F,
    }
    impl<F: Fn(f32) -> f32> macerator::WithSimd for Map<'_, F> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: macerator::Simd>(self) {
            for v in self.values.iter_mut() {
                *v = (self.f)(*v);
            }
        }
    }
    vectorized(Map { values, f });
}

/// The right-hand factor of `matrix_product`, row-major: `AsIs(b)` is `[k, n]`; `Transposed(b)`
/// is `[n, k]`, multiplied as its transpose without a transposed copy.
#[derive(Clone, Copy, Debug)]
pub enum Right<'a> {
    AsIs(&'a [f32]),
    Transposed(&'a [f32]),
}

/// Where `matrix_product` runs: on the calling thread (the caller spreads its independent
/// products over the cores), or on every core of rayon's pool, gemm splitting the one product
/// as burn's CPU backend has it do (the packed operands shared, not packed once per core).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Cores {
    One,
    All,
}

/// `dst = scale · a b`, or `dst += scale · a b` when `accumulate`, for `a` `[m, k]` and `dst`
/// `[m, n]`, row-major, by `gemm` (the micro-kernels burn's CPU backend calls).
///
/// # Panics
/// When a slice's length is not what `[m, n, k]` says.
#[allow(unsafe_code)] // gemm's interface is raw pointers and strides
pub fn matrix_product(
    dst: &mut [f32],
    a: &[f32],
    b: Right<'_>,
    [m, n, k]: [usize; 3],
    scale: f32,
    accumulate: bool,
    cores: Cores,
) {
    let (b, b_column_stride, b_row_stride) = match b {
        Right::AsIs(b) => (b, 1, n),
        Right::Transposed(b) => (b, k, 1),
    };
    assert_eq!(dst.len(), m * n, "the product's [m, n]");
    assert_eq!(a.len(), m * k, "the left factor's [m, k]");
    assert_eq!(b.len(), k * n, "the right factor's [k, n]");
    // SAFETY: with the lengths checked above, every element gemm reads or writes lies in its
    // slice: a[i·k + l], b[l·row + j·column] and dst[i·n + j] for i < m, j < n, l < k.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            1,
            n as isize,
            accumulate,
            a.as_ptr(),
            1,
            k as isize,
            b.as_ptr(),
            b_column_stride as isize,
            b_row_stride as isize,
            if accumulate { 1.0 } else { 0.0 },
            scale,
            false,
            false,
            false,
            match cores {
                Cores::One => gemm::Parallelism::None,
                Cores::All => gemm::Parallelism::Rayon(0),
            },
        );
    }
}

/// A matrix placed in a buffer by strides: element `(i, j)` at `offset + i·row + j·column`.
/// The heads of a packed `[tokens, 3·C]` projection, or one token of every frame, are matrices
/// of this kind: a kernel multiplies them where they lie instead of copying them out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Placed {
    pub offset: usize,
    pub row: usize,
    pub column: usize,
}

impl Placed {
    /// A row-major `[_, columns]` matrix from `offset`.
    pub fn rows(offset: usize, columns: usize) -> Self {
        Self {
            offset,
            row: columns,
            column: 1,
        }
    }

    /// One past the largest index of its `[rows, columns]` elements; 0 when it has none.
    pub fn end(&self, rows: usize, columns: usize) -> usize {
        if rows == 0 || columns == 0 {
            return 0;
        }
        self.offset + (rows - 1) * self.row + (columns - 1) * self.column + 1
    }
}

/// A buffer that threads write at once, each to elements no other touches: the output of a
/// kernel whose tasks' results interleave in memory (one attention head's channels on every
/// token row), where `chunks_mut` cannot hand out the pieces.
pub struct DisjointWrites<'a> {
    start: *mut f32,
    len: usize,
    _buffer: std::marker::PhantomData<&'a mut [f32]>,
}

// SAFETY: the buffer is borrowed mutably for 'a, and `placed_product`'s contract makes every
// caller write elements that no other thread reads or writes.
#[allow(unsafe_code)]
unsafe impl Send for DisjointWrites<'_> {}
#[allow(unsafe_code)]
unsafe impl Sync for DisjointWrites<'_> {}

impl<'a> DisjointWrites<'a> {
    pub fn new(buffer: &'a mut [f32]) -> Self {
        Self {
            start: buffer.as_mut_ptr(),
            len: buffer.len(),
            _buffer: std::marker::PhantomData,
        }
    }
}

/// `dst = scale · a b`, or `dst += scale · a b` when `accumulate`, for `a` `[m, k]`, `b`
/// `[k, n]` and `dst` `[m, n]`, each placed in its buffer by strides, on the calling thread.
///
/// # Safety
/// No other thread reads or writes the `[m, n]` elements of `dst` during the call.
///
/// # Panics
/// When a matrix reaches past the end of its buffer.
#[allow(unsafe_code)] // gemm's interface is raw pointers and strides
#[allow(clippy::too_many_arguments)] // three placed matrices, their sizes and gemm's two factors
pub unsafe fn placed_product(
    dst: &DisjointWrites<'_>,
    dst_at: Placed,
    a: &[f32],
    a_at: Placed,
    b: &[f32],
    b_at: Placed,
    [m, n, k]: [usize; 3],
    scale: f32,
    accumulate: bool,
) {
    assert!(
        dst_at.end(m, n) <= dst.len,
        "the product reaches past its buffer"
    );
    assert!(
        a_at.end(m, k) <= a.len(),
        "the left factor reaches past its buffer"
    );
    assert!(
        b_at.end(k, n) <= b.len(),
        "the right factor reaches past its buffer"
    );
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        // gemm reads no factor then; `dst = 0` still holds, and `dst += 0` leaves it.
        if !accumulate {
            for i in 0..m {
                for j in 0..n {
                    // SAFETY: within the buffer (checked above), and ours alone (the contract).
                    unsafe {
                        *dst.start
                            .add(dst_at.offset + i * dst_at.row + j * dst_at.column) = 0.0;
                    }
                }
            }
        }
        return;
    }
    // SAFETY: every element gemm reads or writes lies in its buffer (the ends checked above);
    // the caller keeps other threads off dst's elements.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.start.add(dst_at.offset),
            dst_at.column as isize,
            dst_at.row as isize,
            accumulate,
            a.as_ptr().add(a_at.offset),
            a_at.column as isize,
            a_at.row as isize,
            b.as_ptr().add(b_at.offset),
            b_at.column as isize,
            b_at.row as isize,
            if accumulate { 1.0 } else { 0.0 },
            scale,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}
