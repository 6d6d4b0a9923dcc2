//! Multi-head scaled dot-product attention (Vaswani et al. 2017),
//! `softmax(Q Kᵀ / √d + B) V`, with an additive bias `B` that carries masks and learned
//! position biases. Swin's window attention and the world model's spatial and temporal
//! attention all go through `scaled_dot_product` under autodiff and on other devices; for
//! inference on the CPU, Swin runs its own window kernel and the world model
//! `MultiHeadAttention::forward_rows_on_host`.

use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::activation::softmax_last;
use crate::attention_on_host::{
    EarlierKeysValues, HeadBias, HeadShapes, SequenceRows, attention_on_host,
    packed_attention_on_host, unpack_heads,
};
use crate::host::{checked_values, runs_on_host};
use crate::linear_on_host::{linear, linear_values};

/// Additive attention bias for token pairs that must not attend to each other. Large enough
/// that `exp` gives exactly 0 in f32, finite so that no backward pass ever sees `inf - inf`.
pub const MASKED: f32 = -1e9;

/// `softmax(q kᵀ / √d + bias) v`, the bias broadcast over the batch and head axes where it has
/// size 1 there. For inference on the CPU, one kernel per head (`attention_on_host`); under
/// autodiff and on other devices, burn's ops with their backward passes.
// q: [B, H, Nq, d], k, v: [B, H, Nk, d], bias: [B | 1, H | 1, Nq, Nk] -> [B, H, Nq, d]
pub fn scaled_dot_product(
    q: Tensor<4>,
    k: Tensor<4>,
    v: Tensor<4>,
    bias: Option<Tensor<4>>,
) -> Tensor<4> {
    if runs_on_host(&q) && runs_on_host(&k) && runs_on_host(&v) {
        return scaled_dot_product_on_host(q, k, v, bias);
    }
    let logits = attention_logits(q, k);
    attend(
        match bias {
            Some(bias) => logits + bias,
            None => logits,
        },
        v,
    )
}

/// `scaled_dot_product` by `attention_on_host`: the tensors' values, one kernel per head.
// q: [B, H, Nq, d], k, v: [B, H, Nk, d], bias: [B | 1, H | 1, Nq, Nk] -> [B, H, Nq, d]
fn scaled_dot_product_on_host(
    q: Tensor<4>,
    k: Tensor<4>,
    v: Tensor<4>,
    bias: Option<Tensor<4>>,
) -> Tensor<4> {
    let device = q.device();
    let [batch, heads, queries, dim] = q.dims();
    let keys = k.dims()[2];
    // The bias keeps its size-1 batch and head axes: the kernel broadcasts them.
    let bias = bias.map(|b| {
        let [bias_batch, bias_heads, ..] = b.dims();
        let values = b
            .expand([bias_batch, bias_heads, queries, keys])
            .into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .expect("data converted to f32 reads as f32");
        (values, bias_batch, bias_heads)
    });
    let out = attention_on_host(
        &checked_values(q),
        &checked_values(k),
        &checked_values(v),
        bias.as_ref().map(|(values, batch, heads)| HeadBias {
            values,
            batch: *batch,
            heads: *heads,
        }),
        HeadShapes {
            batch,
            heads,
            queries,
            keys,
            dim,
        },
    );
    Tensor::from_data(TensorData::new(out, [batch, heads, queries, dim]), &device)
}

/// `q kᵀ / √d`, for callers that add a bias of their own layout before `attend`.
// q, k: [B, H, N, d] -> [B, H, N, N]
pub fn attention_logits(q: Tensor<4>, k: Tensor<4>) -> Tensor<4> {
    let [_, _, _, head_dim] = q.dims();
    let scale = (head_dim as f64).powf(-0.5);
    q.mul_scalar(scale).matmul(k.swap_dims(2, 3))
}

/// `softmax(logits) v`.
// logits: [B, H, N, N], v: [B, H, N, d] -> [B, H, N, d]
pub fn attend(logits: Tensor<4>, v: Tensor<4>) -> Tensor<4> {
    softmax_last(logits).matmul(v)
}

/// Projects tokens to per-head queries, keys and values with one fused linear layer.
// x: [B, N, C] -> 3 × [B, H, N, C / H]
pub fn split_heads(qkv: &Linear, x: Tensor<3>, heads: usize) -> [Tensor<4>; 3] {
    let [batch, tokens, dim] = x.dims();
    let head_dim = dim / heads;
    let qkv = linear(qkv, x)
        .reshape([batch, tokens, 3, heads, head_dim])
        .permute([2, 0, 3, 1, 4]); // [3, B, H, N, d]
    let part = |i: usize| {
        qkv.clone()
            .narrow(0, i, 1)
            .reshape([batch, heads, tokens, head_dim])
    };
    [part(0), part(1), part(2)]
}

/// Joins the heads back and applies the output projection.
// out: [B, H, N, d] -> [B, N, H·d]
pub fn merge_heads(proj: &Linear, out: Tensor<4>) -> Tensor<3> {
    let [batch, heads, tokens, head_dim] = out.dims();
    linear(
        proj,
        out.swap_dims(1, 2)
            .reshape([batch, tokens, heads * head_dim]),
    )
}

/// The additive mask that lets token `i` attend to tokens `j ≤ i` only.
// -> [N, N]
pub fn causal_mask(tokens: usize, device: &Device) -> Tensor<2> {
    let values: Vec<f32> = (0..tokens)
        .flat_map(|i| (0..tokens).map(move |j| if j <= i { 0.0 } else { MASKED }))
        .collect();
    Tensor::from_data(TensorData::new(values, [tokens, tokens]), device)
}

#[derive(Config, Debug)]
pub struct MultiHeadAttentionConfig {
    pub dim: usize,
    pub heads: usize,
}

/// Self-attention over a sequence of tokens.
#[derive(Module, Debug)]
pub struct MultiHeadAttention {
    qkv: Linear,
    proj: Linear,
    #[module(skip)]
    heads: usize,
}

impl MultiHeadAttentionConfig {
    pub fn init(&self, device: &Device) -> MultiHeadAttention {
        MultiHeadAttention {
            qkv: LinearConfig::new(self.dim, 3 * self.dim).init(device),
            proj: LinearConfig::new(self.dim, self.dim).init(device),
            heads: self.heads,
        }
    }
}

impl MultiHeadAttention {
    /// `bias` is added to every head's logits: a mask (`causal_mask`, `MASKED` entries) or a
    /// learned bias.
    // x: [B, N, C], bias: [B | 1, H | 1, N, N] -> [B, N, C]
    pub fn forward(&self, x: Tensor<3>, bias: Option<Tensor<4>>) -> Tensor<3> {
        self.forward_after(x, None, bias).0
    }

    /// Attention of `x`'s tokens over `prefix`'s keys and values followed by their own: the
    /// prefix holds tokens that came before and were projected once (the world model's
    /// condition frames, the same at every sampling step). Returns the output and this call's
    /// own keys and values, to be a later call's prefix.
    // x: [B, N, C], prefix: 2 × [B, H, P, d], bias: [B | 1, H | 1, N, P + N]
    //   -> [B, N, C], 2 × [B, H, N, d]
    pub fn forward_after(
        &self,
        x: Tensor<3>,
        prefix: Option<&[Tensor<4>; 2]>,
        bias: Option<Tensor<4>>,
    ) -> (Tensor<3>, [Tensor<4>; 2]) {
        let [q, k, v] = split_heads(&self.qkv, x, self.heads);
        let (keys, values) = match prefix {
            Some([earlier_k, earlier_v]) => (
                Tensor::cat(vec![earlier_k.clone(), k.clone()], 2),
                Tensor::cat(vec![earlier_v.clone(), v.clone()], 2),
            ),
            None => (k.clone(), v.clone()),
        };
        let out = merge_heads(&self.proj, scaled_dot_product(q, keys, values, bias));
        (out, [k, v])
    }

    /// Self-attention of the sequences that `sequences` lays out among the rows of `x` (every
    /// row of `[.., C]` one token), for inference on the CPU: the packed projection is read
    /// where it lies (`packed_attention_on_host`), with no per-head copies and no regrouping
    /// of the rows into sequences and back. The output keeps `x`'s layout. With `keep`, also
    /// this call's keys and values, `[S, H, N, d]` each, to be a later call's `earlier`.
    /// `bias` is `[N, P + N]`, the same for every sequence and head.
    ///
    /// # Panics
    /// When `x` or the layer is not f32 CPU inference (check `runs_on_host`), or the shapes
    /// disagree with `sequences`.
    // x: [..., C], earlier: 2 × [S, H, P, d], bias: [N, P + N] -> [..., C], 2 × [S, H, N, d]
    pub fn forward_rows_on_host<const D: usize>(
        &self,
        x: Tensor<D>,
        sequences: SequenceRows,
        earlier: Option<&[Tensor<4>; 2]>,
        bias: Option<Tensor<2>>,
        keep: bool,
    ) -> (Tensor<D>, Option<[Tensor<4>; 2]>) {
        let dims = x.dims();
        let device = x.device();
        let channels = dims[D - 1];
        let heads = self.heads;
        let dim = channels / heads;
        let on_host = "an f32 CPU inference layer beside its input";
        let qkv = linear_values(&self.qkv, &checked_values(x)).expect(on_host);
        let earlier_values = earlier.map(|[k, v]| {
            let tokens = k.dims()[2];
            (checked_values(k.clone()), checked_values(v.clone()), tokens)
        });
        let bias = bias.map(checked_values);
        let out = packed_attention_on_host(
            &qkv,
            sequences,
            heads,
            dim,
            earlier_values
                .as_ref()
                .map(|(keys, values, tokens)| EarlierKeysValues {
                    keys,
                    values,
                    tokens: *tokens,
                }),
            bias.as_deref(),
        );
        let y = linear_values(&self.proj, &out).expect(on_host);
        let kept = keep.then(|| {
            let shape = [sequences.sequences(), heads, sequences.length, dim];
            let part = |i: usize| {
                Tensor::from_data(
                    TensorData::new(unpack_heads(&qkv, sequences, heads, dim, i), shape),
                    &device,
                )
            };
            [part(1), part(2)]
        });
        (Tensor::from_data(TensorData::new(y, dims), &device), kept)
    }
}
