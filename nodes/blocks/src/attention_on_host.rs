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
use crate::host::{
    Cores, DisjointWrites, Placed, Right, matrix_product, placed_product, vectorized,
};

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

/// Where the tokens of every sequence lie among a buffer's rows: token `i` of sequence
/// `s = o·inner + n` is row `o·outer_stride + n·inner_stride + i·step`. The world model's
/// tokens are `[B, F, L, D]` rows; its spatial attention runs over each frame's `L` tokens,
/// its temporal attention over each place's `F` frames, and both read the rows where they lie.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SequenceRows {
    pub outer: usize,
    pub outer_stride: usize,
    pub inner: usize,
    pub inner_stride: usize,
    /// Tokens per sequence.
    pub length: usize,
    pub step: usize,
}

impl SequenceRows {
    /// Each of `count` sequences is `length` consecutive rows.
    pub fn consecutive(count: usize, length: usize) -> Self {
        Self {
            outer: count,
            outer_stride: length,
            inner: 1,
            inner_stride: 0,
            length,
            step: 1,
        }
    }

    /// `[B, F, L]` rows, one sequence of `F` frames per `(b, l)`, in that order.
    pub fn across_frames(batch: usize, frames: usize, places: usize) -> Self {
        Self {
            outer: batch,
            outer_stride: frames * places,
            inner: places,
            inner_stride: 1,
            length: frames,
            step: places,
        }
    }

    pub fn sequences(&self) -> usize {
        self.outer * self.inner
    }

    /// The row of token `token` of sequence `sequence`.
    pub fn row(&self, sequence: usize, token: usize) -> usize {
        (sequence / self.inner.max(1)) * self.outer_stride
            + (sequence % self.inner.max(1)) * self.inner_stride
            + token * self.step
    }

    /// Whether every one of `rows` rows is exactly one sequence's token: then the tasks of a
    /// kernel write disjoint rows, and none is left unwritten.
    pub fn tiles(&self, rows: usize) -> bool {
        if self.sequences() * self.length != rows {
            return false;
        }
        let mut seen = vec![false; rows];
        for sequence in 0..self.sequences() {
            for token in 0..self.length {
                match seen.get_mut(self.row(sequence, token)) {
                    Some(slot) if !*slot => *slot = true,
                    _ => return false,
                }
            }
        }
        true
    }
}

/// Keys and values computed before, `[S, H, P, d]` each (one sequence's `P` tokens per head),
/// that every sequence's queries attend to before their own.
#[derive(Clone, Copy, Debug)]
pub struct EarlierKeysValues<'a> {
    pub keys: &'a [f32],
    pub values: &'a [f32],
    pub tokens: usize,
}

/// Self-attention read straight from a packed projection: `qkv` holds `[rows, 3·C]` (each
/// row's queries, keys and values, `C = heads · dim` channels each, head-major within), and the
/// result is `[rows, C]`, every token's heads at the row of its query. Each sequence's queries
/// attend to `earlier`'s keys and values (when given) and then to their own, with `bias`
/// (`[length, P + length]`, the same for every sequence and head) added to the logits.
///
/// Why: the tensor path splits `[.., 3, H, d]` into per-head `[S, H, N, d]` copies, and for
/// attention over frames also regroups the `[B, F, L, D]` tokens by place and back; here every
/// product reads its head where it lies (`placed_product`), one `(sequence, head)` per task.
///
/// # Panics
/// When `qkv` is not `[rows, 3·C]`, the rows are not tiled by `sequences` (every row one
/// token of one sequence), or `earlier` and `bias` are not the sizes above.
// qkv: [R, 3·H·d], earlier: 2 × [S, H, P, d], bias: [N, P + N] -> [R, H·d]
pub fn packed_attention_on_host(
    qkv: &[f32],
    sequences: SequenceRows,
    heads: usize,
    dim: usize,
    earlier: Option<EarlierKeysValues<'_>>,
    bias: Option<&[f32]>,
) -> Vec<f32> {
    let channels = heads * dim;
    assert!(
        channels > 0 && qkv.len().is_multiple_of(3 * channels),
        "qkv is not [rows, 3·{channels}]"
    );
    let rows = qkv.len() / (3 * channels);
    assert!(
        sequences.tiles(rows),
        "{sequences:?} does not tile the {rows} rows"
    );
    let length = sequences.length;
    let prefix = earlier.map_or(0, |e| e.tokens);
    let keys = prefix + length;
    if let Some(e) = &earlier {
        let size = sequences.sequences() * heads * prefix * dim;
        assert_eq!(e.keys.len(), size, "the earlier keys are not [S, H, P, d]");
        assert_eq!(
            e.values.len(),
            size,
            "the earlier values are not [S, H, P, d]"
        );
    }
    if let Some(b) = bias {
        assert_eq!(b.len(), length * keys, "the bias is not [N, P + N]");
    }
    let mut out = vec![0f32; rows * channels];
    if out.is_empty() {
        return out;
    }
    let scale = (dim as f64).powf(-0.5) as f32;
    let packed_row = 3 * channels;
    let writes = DisjointWrites::new(&mut out);
    (0..sequences.sequences() * heads)
        .into_par_iter()
        .for_each_init(
            || vec![0f32; length * keys],
            |logits, task| {
                let (sequence, head) = (task / heads, task % heads);
                let first = sequences.row(sequence, 0);
                let token_stride = sequences.step * packed_row;
                let own = |part: usize| Placed {
                    offset: first * packed_row + part * channels + head * dim,
                    row: token_stride,
                    column: 1,
                };
                let logits_at = |column: usize| Placed {
                    offset: column,
                    row: keys,
                    column: 1,
                };
                let earlier_at = (task * prefix) * dim; // [S, H, P, d]: this head's [P, d]
                let tile = DisjointWrites::new(logits);
                // SAFETY (every placed_product below): `tile` is this task's own buffer, and
                // `writes` is written only at this (sequence, head)'s elements: the rows of
                // its tokens (distinct across sequences, `tiles` checked) at this head's
                // channels (distinct across heads).
                #[allow(unsafe_code)]
                unsafe {
                    // logits = scale · q [earlier keys, own keys]ᵀ, keys read by columns.
                    if let Some(e) = &earlier {
                        placed_product(
                            &tile,
                            logits_at(0),
                            qkv,
                            own(0),
                            e.keys,
                            Placed {
                                offset: earlier_at,
                                row: 1,
                                column: dim,
                            },
                            [length, prefix, dim],
                            scale,
                            false,
                        );
                    }
                    let k = own(1);
                    placed_product(
                        &tile,
                        logits_at(prefix),
                        qkv,
                        own(0),
                        qkv,
                        Placed {
                            offset: k.offset,
                            row: 1,
                            column: k.row,
                        },
                        [length, length, dim],
                        scale,
                        false,
                    );
                }
                vectorized(BiasedSoftmax {
                    logits,
                    bias,
                    row: keys,
                });
                let tile: &[f32] = logits;
                let dst = Placed {
                    offset: first * channels + head * dim,
                    row: sequences.step * channels,
                    column: 1,
                };
                #[allow(unsafe_code)]
                unsafe {
                    // out = softmax(…) [earlier values; own values].
                    if let Some(e) = &earlier {
                        placed_product(
                            &writes,
                            dst,
                            tile,
                            Placed::rows(0, keys),
                            e.values,
                            Placed::rows(earlier_at, dim),
                            [length, dim, prefix],
                            1.0,
                            false,
                        );
                    }
                    placed_product(
                        &writes,
                        dst,
                        tile,
                        Placed::rows(prefix, keys),
                        qkv,
                        own(2),
                        [length, dim, length],
                        1.0,
                        earlier.is_some(),
                    );
                }
            },
        );
    out
}

/// One sequence's own keys or values (`part` 1 or 2) out of a packed projection, as
/// `[S, H, N, d]`: what a later call attends to as `EarlierKeysValues`.
// qkv: [R, 3·H·d] -> [S, H, N, d]
pub fn unpack_heads(
    qkv: &[f32],
    sequences: SequenceRows,
    heads: usize,
    dim: usize,
    part: usize,
) -> Vec<f32> {
    let channels = heads * dim;
    let mut out = Vec::with_capacity(sequences.sequences() * sequences.length * channels);
    for sequence in 0..sequences.sequences() {
        for head in 0..heads {
            for token in 0..sequences.length {
                let at =
                    sequences.row(sequence, token) * 3 * channels + part * channels + head * dim;
                out.extend_from_slice(&qkv[at..at + dim]);
            }
        }
    }
    out
}
