//! The world model's attention on CPU inference reads its packed `[rows, 3·C]` projection where
//! it lies (`MultiHeadAttention::forward_rows_on_host`); the tensor path splits heads into
//! copies and regroups `[B, F, L, D]` by place for attention over frames. Both must agree for
//! the two layouts the world model uses: each frame's tokens in consecutive rows, and each
//! place's frames `L` rows apart, the latter after cached earlier frames under a causal mask,
//! keys and values kept included. The row arithmetic and the strided products are checked by
//! hand, and layouts whose tasks would write the same rows are refused.

use bevworld_blocks::attention::{MultiHeadAttention, MultiHeadAttentionConfig, causal_mask};
use bevworld_blocks::attention_on_host::{SequenceRows, packed_attention_on_host};
use bevworld_blocks::host::{DisjointWrites, Placed, placed_product};
use bevworld_blocks::init::random_normal;
use bevworld_blocks::seeded_init;
use burn::module::Module;
use burn::prelude::*;

use crate::compare::largest_difference;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

fn layer(width: usize, heads: usize, device: &Device) -> MultiHeadAttention {
    seeded_init(7, device, |d| {
        MultiHeadAttentionConfig::new(width, heads).init(d)
    })
}

#[test]
fn attention_within_frames_agrees_with_the_tensor_path() {
    // The tiny world model's spatial attention: 2 × 3 frames of 64 tokens, 4 heads of 8.
    let host = Device::flex();
    let attention = layer(32, 4, &host);
    let x = random_normal(1, [2, 3, 64, 32], 0.0, 1.0, &host);
    let (on_host, kept) = attention.forward_rows_on_host(
        x.clone(),
        SequenceRows::consecutive(6, 64),
        None,
        None,
        false,
    );
    assert!(kept.is_none(), "keys and values are kept only when asked");
    let autodiff = host.autodiff();
    let on_tensors = attention
        .clone()
        .to_device(&autodiff)
        .forward(
            Tensor::<4>::from_data(x.into_data(), &autodiff).reshape([6, 64, 32]),
            None,
        )
        .reshape([2, 3, 64, 32]);
    let worst = largest_difference(&values(on_host), &values(on_tensors));
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn attention_across_frames_after_earlier_ones_agrees_with_the_tensor_path() {
    // Temporal attention of 2 future frames over 3 cached ones: [B = 2, F = 2, L = 9, D = 16],
    // 2 heads; the earlier keys and values are [B·L, H, P, d] in (b, l) order.
    let host = Device::flex();
    let (batch, frames, places, width, heads, earlier) = (2, 2, 9, 16, 2, 3);
    let attention = layer(width, heads, &host);
    let x = random_normal(2, [batch, frames, places, width], 0.0, 1.0, &host);
    let prefix = [
        random_normal(
            3,
            [batch * places, heads, earlier, width / heads],
            0.0,
            1.0,
            &host,
        ),
        random_normal(
            4,
            [batch * places, heads, earlier, width / heads],
            0.0,
            1.0,
            &host,
        ),
    ];
    let mask = causal_mask(earlier + frames, &host).narrow(0, earlier, frames); // [F, P + F]
    let (on_host, kept) = attention.forward_rows_on_host(
        x.clone(),
        SequenceRows::across_frames(batch, frames, places),
        Some(&prefix),
        Some(mask.clone()),
        true,
    );
    let [kept_keys, kept_values] = kept.expect("kept when asked");

    let autodiff = host.autodiff();
    let to = |t: Tensor<4>| Tensor::<4>::from_data(t.into_data(), &autodiff);
    let h = to(x)
        .swap_dims(1, 2)
        .reshape([batch * places, frames, width]);
    let (out, [keys, values_kept]) = attention.clone().to_device(&autodiff).forward_after(
        h,
        Some(&[to(prefix[0].clone()), to(prefix[1].clone())]),
        Some(Tensor::<2>::from_data(mask.into_data(), &autodiff).unsqueeze::<4>()),
    );
    let out = out.reshape([batch, places, frames, width]).swap_dims(1, 2);
    for (name, a, b) in [
        ("output", values(on_host), values(out)),
        ("keys", values(kept_keys), values(keys)),
        ("values", values(kept_values), values(values_kept)),
    ] {
        let worst = largest_difference(&a, &b);
        assert!(worst < 1e-5, "{name}: {worst}");
    }
}

#[test]
fn rows_of_frames_worked_out_by_hand() {
    // [B = 2, F = 3, L = 4]: place l of batch b, frame f, is row (b·3 + f)·4 + l.
    let across = SequenceRows::across_frames(2, 3, 4);
    assert_eq!(across.sequences(), 8);
    // Sequence 5 is (b = 1, l = 1): rows 13, 17, 21.
    assert_eq!(
        (0..3).map(|f| across.row(5, f)).collect::<Vec<_>>(),
        [13, 17, 21]
    );
    assert!(across.tiles(24));
    assert!(!across.tiles(25), "a row no sequence holds");
    let within = SequenceRows::consecutive(3, 5);
    assert_eq!(within.row(2, 4), 14);
    assert!(within.tiles(15));
}

#[test]
fn layouts_whose_sequences_share_rows_are_refused() {
    // Sequences 0 and 1 would both start at row 0: their tasks would write the same rows.
    let overlapping = SequenceRows {
        outer: 2,
        outer_stride: 0,
        inner: 1,
        inner_stride: 0,
        length: 2,
        step: 1,
    };
    assert!(!overlapping.tiles(4));
    let qkv = vec![0.0; 4 * 3 * 2];
    let refused =
        std::panic::catch_unwind(|| packed_attention_on_host(&qkv, overlapping, 1, 2, None, None));
    let message = refused.expect_err("refused");
    let text = message
        .downcast_ref::<String>()
        .cloned()
        .unwrap_or_default();
    assert!(text.contains("does not tile the 4 rows"), "{text}");
}

#[test]
fn a_placed_product_worked_out_by_hand() {
    // a = [[1, 2], [3, 4]] stored by columns at offset 1: [_, 1, 3, 2, 4].
    // b = [[1, 0, 2], [0, 1, 1]] stored row-major with rows 4 apart: [1, 0, 2, _, 0, 1, 1].
    // a b = [[1, 2, 4], [3, 4, 10]]; scaled by 2, written by columns into rows 1 apart.
    let a = [9.0, 1.0, 3.0, 2.0, 4.0];
    let b = [1.0, 0.0, 2.0, 9.0, 0.0, 1.0, 1.0];
    let mut dst = [0.0f32; 6];
    let writes = DisjointWrites::new(&mut dst);
    // SAFETY: one thread, one buffer.
    #[allow(unsafe_code)]
    unsafe {
        placed_product(
            &writes,
            Placed {
                offset: 0,
                row: 1,
                column: 2,
            },
            &a,
            Placed {
                offset: 1,
                row: 1,
                column: 2,
            },
            &b,
            Placed {
                offset: 0,
                row: 4,
                column: 1,
            },
            [2, 3, 2],
            2.0,
            false,
        );
    }
    assert_eq!(dst, [2.0, 6.0, 4.0, 8.0, 8.0, 20.0]);
}

#[test]
#[should_panic(expected = "the right factor reaches past its buffer")]
fn a_placed_factor_past_its_buffer_is_refused() {
    let mut dst = [0.0f32; 4];
    let writes = DisjointWrites::new(&mut dst);
    // SAFETY: one thread, one buffer.
    #[allow(unsafe_code)]
    unsafe {
        placed_product(
            &writes,
            Placed::rows(0, 2),
            &[1.0; 4],
            Placed::rows(0, 2),
            &[1.0; 3],
            Placed::rows(0, 2),
            [2, 2, 2],
            1.0,
            false,
        );
    }
}
