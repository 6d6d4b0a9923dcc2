//! Linear layers on CPU inference run as our own products (`linear_on_host`); under autodiff
//! they run `Linear::forward`. Both must agree with and without a bias, with GELU after, for
//! a product large enough for gemm to split over the cores, and for inputs of any rank. A worked example pins the layout of the weights (`[C_in, C_out]`, burn's).

use bevworld_blocks::activation::gelu;
use bevworld_blocks::init::random_normal;
use bevworld_blocks::linear_on_host::{linear, linear_gelu};
use bevworld_blocks::seeded_init;
use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::prelude::*;

use crate::compare::largest_difference;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

fn layer_difference<const D: usize>(layer: &Linear, x: Tensor<D>, then_gelu: bool) -> f32 {
    let on_host = values(if then_gelu {
        linear_gelu(layer, x.clone())
    } else {
        linear(layer, x.clone())
    });
    let autodiff = x.device().autodiff();
    let layer = layer.clone().to_device(&autodiff);
    let y = layer.forward(Tensor::<D>::from_data(x.into_data(), &autodiff));
    let on_tensors = values(if then_gelu { gelu(y) } else { y });
    largest_difference(&on_host, &on_tensors)
}

#[test]
fn agrees_with_the_tensor_path_with_and_without_bias_and_gelu() {
    let host = Device::flex();
    for bias in [true, false] {
        let layer = seeded_init(3, &host, |d| {
            LinearConfig::new(40, 24).with_bias(bias).init(d)
        });
        // 3 × 7 × 110 = 2310 rows: past gemm's threshold for splitting over the cores.
        let x = random_normal(4, [3, 7, 110, 40], 0.0, 1.0, &host);
        for then_gelu in [false, true] {
            let worst = layer_difference(&layer, x.clone(), then_gelu);
            assert!(worst < 1e-5, "bias {bias}, gelu {then_gelu}: {worst}");
        }
        // One row, rank 1.
        let x = random_normal(5, [40], 0.0, 1.0, &host);
        let worst = layer_difference(&layer, x, false);
        assert!(worst < 1e-5, "one row, bias {bias}: {worst}");
    }
}

#[test]
fn a_worked_example() {
    // W = [[1, 2, 3], [4, 5, 6]] ([C_in = 2, C_out = 3]), b = (0.5, 0, −1), x = (1, −1):
    // x W + b = (1 − 4, 2 − 5, 3 − 6) + b = (−2.5, −3, −4).
    let host = Device::flex();
    let layer = Linear {
        weight: burn::module::Param::from_tensor(Tensor::from_data(
            [[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]],
            &host,
        )),
        bias: Some(burn::module::Param::from_tensor(Tensor::from_data(
            [0.5f32, 0.0, -1.0],
            &host,
        ))),
    };
    let y = values(linear(
        &layer,
        Tensor::<2>::from_data([[1.0f32, -1.0]], &host),
    ));
    assert_eq!(y, vec![-2.5, -3.0, -4.0]);
}
