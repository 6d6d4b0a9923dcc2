//! `softmax(q kᵀ / √d + bias) v` for inference on the CPU, one (batch, head) at a time: its
//! logits are made, biased, normalised and multiplied by `v` while they sit in the core's
//! cache, then dropped.
//!
//! Why our own: burn's ops run attention as four passes over the whole `[B, H, N, N]` logits
//! (the product, the bias, the softmax, the product with `v`). For the world model's spatial
//! attention that is 9 MB a block, past the L2 cache, read and written four times; on an
//! AVX-512 Xeon its softmax alone was a fifth of a network pass. Here one head's logits
//! (256 × 256 floats for the tiny world model, 256 KB) never leave L2, the scale rides in the
//! product, and the heads are spread over the cores. The products are `gemm`'s, the same
//! micro-kernels burn's CPU backend calls; the softmax is `softmax_row`, the same as every
//! other softmax of ours.

use rayon::prelude::*;

use crate::activation::softmax_row;
use crate::host::{Cores, Right, matrix_product, vectorized};

/// The sizes of one attention call: `batch × heads` independent heads, each with `queries`
/// query rows, `keys` key and value rows, and `dim` channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeadShapes {
    pub batch: usize,
    pub heads: usize,
    pub queries: usize,
    pub keys: usize,
    pub dim: usize,
}

/// An additive bias over each head's `[queries, keys]` logits, row-major, with its batch and
/// head extents (each the call's or 1: broadcast without copying).
#[derive(Clone, Copy, Debug)]
pub struct HeadBias<'a> {
    pub values: &'a [f32],
    pub batch: usize,
    pub heads: usize,
}

/// The attention of every head: `q` is `[B, H, Nq, d]`, `k` and `v` are `[B, H, Nk, d]`, all
/// row-major; the result is `[B, H, Nq, d]`.
///
/// # Panics
/// When a slice's length is not what `shapes` says, or the bias's extents are neither the
/// call's nor 1: the tensor path checks the same shapes before calling.
// q: [B, H, Nq, d], k, v: [B, H, Nk, d], bias: [B | 1, H | 1, Nq, Nk] -> [B, H, Nq, d]
pub fn attention_on_host(
    q: &[f32],
    k: &[f32],
    v: &[f32],
    bias: Option<HeadBias<'_>>,
    shapes: HeadShapes,
) -> Vec<f32> {
    let HeadShapes {
        batch,
        heads,
        queries,
        keys,
        dim,
    } = shapes;
    let (q_head, kv_head, tile) = (queries * dim, keys * dim, queries * keys);
    assert_eq!(q.len(), batch * heads * q_head, "q is not [B, H, Nq, d]");
    assert_eq!(k.len(), batch * heads * kv_head, "k is not [B, H, Nk, d]");
    assert_eq!(v.len(), batch * heads * kv_head, "v is not [B, H, Nk, d]");
    if let Some(b) = &bias {
        assert!(
            (b.batch == batch || b.batch == 1) && (b.heads == heads || b.heads == 1),
            "the bias's [{}, {}] does not broadcast to [{batch}, {heads}]",
            b.batch,
            b.heads
        );
        assert_eq!(b.values.len(), b.batch * b.heads * tile, "the bias's tiles");
    }
    let mut out = vec![0f32; batch * heads * q_head];
    if out.is_empty() {
        return out;
    }
    let scale = (dim as f64).powf(-0.5) as f32;
    out.par_chunks_mut(q_head).enumerate().for_each_init(
        || vec![0f32; tile],
        |logits, (index, out)| {
            let (b, h) = (index / heads, index % heads);
            let head_bias = bias.map(|bias| {
                let at = ((b % bias.batch) * bias.heads + h % bias.heads) * tile;
                &bias.values[at..at + tile]
            });
            let qs = &q[index * q_head..(index + 1) * q_head];
            let ks = &k[index * kv_head..(index + 1) * kv_head];
            let vs = &v[index * kv_head..(index + 1) * kv_head];
            // logits = scale · q kᵀ: k read by columns, so no transposed copy is made.
            matrix_product(
                logits,
                qs,
                Right::Transposed(ks),
                [queries, keys, dim],
                scale,
                false,
                Cores::One,
            );
            vectorized(BiasedSoftmax {
                logits,
                bias: head_bias,
                row: keys,
            });
            // out = softmax(…) v.
            matrix_product(
                out,
                logits,
                Right::AsIs(vs),
                [queries, dim, keys],
                1.0,
                false,
                Cores::One,
            );
        },
    );
    out
}

/// Adds a head's bias to its logits and normalises every row, as one vectorised kernel.
struct BiasedSoftmax<'a> {
    logits: &'a mut [f32],
    bias: Option<&'a [f32]>,
    row: usize,
}

impl macerator::WithSimd for BiasedSoftmax<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        if let Some(bias) = self.bias {
            for (l, &b) in self.logits.iter_mut().zip(bias) {
                *l += b;
            }
        }
        for values in self.logits.chunks_exact_mut(self.row) {
            softmax_row(values);
        }
    }
}
