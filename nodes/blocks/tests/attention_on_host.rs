//! `scaled_dot_product` on CPU inference runs one kernel per head (`attention_on_host`); under
//! autodiff it runs burn's ops. Both must agree for every layout the models use: the world
//! model's spatial attention (no bias), its causal temporal attention over cached earlier
//! frames (fewer queries than keys, a mask shared by every head), and biases given per head or
//! per batch item. A worked example pins the kernel to the formula itself.

use bevworld_blocks::attention::{MASKED, scaled_dot_product};
use bevworld_blocks::attention_on_host::{HeadBias, HeadShapes, attention_on_host};
use bevworld_blocks::init::random_normal;
use burn::prelude::*;

use crate::compare::largest_difference;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

/// The largest difference between the host kernel and burn's ops for one call.
fn call_difference(q: [usize; 4], keys: usize, bias: Option<[usize; 4]>) -> f32 {
    let host = Device::flex();
    let [batch, heads, _, dim] = q;
    let q = random_normal(1, q, 0.0, 1.0, &host);
    let k = random_normal(2, [batch, heads, keys, dim], 0.0, 1.0, &host);
    let v = random_normal(3, [batch, heads, keys, dim], 0.0, 1.0, &host);
    let bias = bias.map(|shape| random_normal(4, shape, 0.0, 2.0, &host));
    let on_host = values(scaled_dot_product(
        q.clone(),
        k.clone(),
        v.clone(),
        bias.clone(),
    ));
    let autodiff = host.autodiff();
    let to = |t: Tensor<4>| Tensor::<4>::from_data(t.into_data(), &autodiff);
    let on_tensors = values(scaled_dot_product(to(q), to(k), to(v), bias.map(to)));
    largest_difference(&on_host, &on_tensors)
}

#[test]
fn spatial_attention_agrees_with_the_tensor_path() {
    // The tiny world model's spatial attention: 9 frames × 4 heads of 256 tokens, 32 channels.
    let worst = call_difference([9, 4, 256, 32], 256, None);
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn biases_broadcast_as_on_the_tensor_path() {
    for bias in [[1, 1, 7, 7], [1, 3, 7, 7], [2, 1, 7, 7], [2, 3, 7, 7]] {
        let worst = call_difference([2, 3, 7, 16], 7, Some(bias));
        assert!(worst < 1e-5, "bias {bias:?}: {worst}");
    }
}

#[test]
fn fewer_queries_than_keys_agree_with_the_tensor_path() {
    // Temporal attention after a cache: 6 future frames attend to 3 cached and themselves.
    let worst = call_difference([16, 4, 6, 32], 9, Some([1, 1, 6, 9]));
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn a_worked_example_and_a_masked_key() {
    // One head, d = 4 (scale ½), two queries, two keys.
    // q0 = (2, 0, 0, 0), q1 = (0, 2, 0, 0); k0 = (1, 0, 0, 0), k1 = (0, 1, 0, 0).
    // Logits: q0 → (1, 0), q1 → (0, 1). v0 = (1, 0, 0, 0), v1 = (0, 3, 0, 0).
    // Row 0: softmax(1, 0) = (e/(e+1), 1/(e+1)) → (0.7311, 3 · 0.2689, 0, 0).
    // Row 1 with key 1 masked: all weight on key 0 → (1, 0, 0, 0).
    let q = [2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0];
    let k = [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    let v = [1.0, 0.0, 0.0, 0.0, 0.0, 3.0, 0.0, 0.0];
    let bias = [0.0, 0.0, 0.0, MASKED];
    let shapes = HeadShapes {
        batch: 1,
        heads: 1,
        queries: 2,
        keys: 2,
        dim: 4,
    };
    let out = attention_on_host(
        &q,
        &k,
        &v,
        Some(HeadBias {
            values: &bias,
            batch: 1,
            heads: 1,
        }),
        shapes,
    );
    let e = std::f32::consts::E;
    let expected = [e / (e + 1.0), 3.0 / (e + 1.0), 0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
    for (i, (a, b)) in out.iter().zip(expected).enumerate() {
        assert!((a - b).abs() < 1e-6, "element {i}: {a} against {b}");
    }
}

#[test]
#[should_panic(expected = "does not broadcast")]
fn a_bias_that_does_not_broadcast_is_refused() {
    let shapes = HeadShapes {
        batch: 2,
        heads: 2,
        queries: 1,
        keys: 1,
        dim: 1,
    };
    let ones = [1.0; 4];
    let bias = [0.0; 3];
    attention_on_host(
        &ones,
        &ones,
        &ones,
        Some(HeadBias {
            values: &bias,
            batch: 3,
            heads: 1,
        }),
        shapes,
    );
}
