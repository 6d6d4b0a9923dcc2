//! Our vectorised softmax over the last axis against hand computations and burn's, with its
//! hard cases: masked entries (`MASKED`), rows longer than the kernel's lanes, a row of equal
//! values, large logits that would overflow a naive `exp`. Autodiff keeps burn's op.

use bevworld_blocks::MASKED;
use bevworld_blocks::activation::{softmax_last, softmax_rows_in_place};
use burn::prelude::*;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

#[test]
fn softmax_of_a_hand_computed_row() {
    // softmax(0, ln 2, ln 3) = (1, 2, 3) / 6.
    let mut row = vec![0.0, 2f32.ln(), 3f32.ln()];
    softmax_rows_in_place(&mut row, 3);
    for (got, want) in row.iter().zip([1.0 / 6.0, 2.0 / 6.0, 3.0 / 6.0]) {
        assert!((got - want).abs() < 1e-7, "{row:?}");
    }
}

#[test]
fn masked_entries_get_exactly_zero_and_large_logits_do_not_overflow() {
    let mut row = vec![1000.0, MASKED, 1000.0, MASKED];
    softmax_rows_in_place(&mut row, 4);
    assert_eq!(row, vec![0.5, 0.0, 0.5, 0.0]);
    let mut equal = vec![-3.0; 37];
    softmax_rows_in_place(&mut equal, 37);
    for v in &equal {
        assert!((v - 1.0 / 37.0).abs() < 1e-8);
    }
    let mut empty: Vec<f32> = Vec::new();
    softmax_rows_in_place(&mut empty, 0);
}

#[test]
fn softmax_matches_burns_on_cpu_inference_tensors() {
    let device = Device::flex();
    // 3 x 5 rows of 67 values (past the 16 lanes, with a remainder), spread over [-20, 20].
    let shape = [3, 5, 67];
    let n: usize = shape.iter().product();
    let xs: Vec<f32> = (0..n)
        .map(|i| ((i * 7919) % 4001) as f32 / 100.0 - 20.0)
        .collect();
    let input = Tensor::<3>::from_data(TensorData::new(xs, shape), &device);
    let ours = softmax_last(input.clone());
    assert_eq!(ours.dims(), shape);
    let ours = values(ours);
    let burns = values(burn::tensor::activation::softmax(input, 2));
    for (a, b) in ours.iter().zip(&burns) {
        assert!((a - b).abs() <= 1e-6 * b.max(1e-3), "ours {a}, burn's {b}");
    }
    for row in ours.chunks(67) {
        let sum: f32 = row.iter().sum();
        assert!((sum - 1.0).abs() < 1e-5, "a row sums to {sum}");
    }
}

#[test]
fn under_autodiff_softmax_is_burns() {
    let device = Device::flex().autodiff();
    let x = Tensor::<2>::from_data(
        TensorData::new(vec![0.1f32, -2.0, 3.0, 0.5], [2, 2]),
        &device,
    )
    .require_grad();
    let reference = burn::tensor::activation::softmax(x.clone().detach(), 1);
    let y = softmax_last(x.clone());
    assert_eq!(values(y.clone()), values(reference));
    let gradients = y.narrow(1, 0, 1).sum().backward();
    assert!(
        x.grad(&gradients).is_some(),
        "the gradient flows through burn's op"
    );
}
