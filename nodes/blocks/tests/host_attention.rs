//! Swin blocks on CPU inference run their attention as one host kernel (`host_attention`);
//! under autodiff they run burn's ops. Both must give the same block output for every kind of
//! window the backbones meet: plain and shifted windows, maps padded to a multiple of the
//! window, a map smaller than the window, several images in a batch.

use bevworld_blocks::init::random_normal;
use bevworld_blocks::seeded_init;
use bevworld_blocks::swin::SwinBlockConfig;
use burn::module::Module;
use burn::prelude::*;

use crate::compare::largest_difference;

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec::<f32>().expect("f32")
}

/// The largest difference between the host kernel and the tensor ops for one block and map.
fn block_difference(
    dim: usize,
    heads: usize,
    window: usize,
    shifted: bool,
    map: [usize; 4],
) -> f32 {
    let host = Device::flex();
    let block = seeded_init(7, &host, |d| {
        SwinBlockConfig::new(dim, heads, window)
            .with_shifted(shifted)
            .init(d)
    });
    let x = random_normal(11, map, 0.0, 1.0, &host);
    let on_host = values(block.forward(x.clone()));
    let autodiff = host.clone().autodiff();
    let on_tensors = values(
        block
            .to_device(&autodiff)
            .forward(Tensor::from_data(x.into_data(), &autodiff)),
    );
    largest_difference(&on_host, &on_tensors)
}

#[test]
fn plain_and_shifted_windows_agree_with_the_tensor_path() {
    for shifted in [false, true] {
        let worst = block_difference(16, 2, 4, shifted, [1, 8, 12, 16]);
        assert!(worst < 1e-5, "shifted {shifted}: {worst}");
    }
}

#[test]
fn padded_maps_and_batches_agree_with_the_tensor_path() {
    // 8 x 14 with window 4 pads to 8 x 16 (the image backbone's second stage), two images.
    for shifted in [false, true] {
        let worst = block_difference(32, 4, 4, shifted, [2, 8, 14, 32]);
        assert!(worst < 1e-5, "shifted {shifted}: {worst}");
    }
    // 10 x 10 with window 4: padded on both axes.
    let worst = block_difference(8, 2, 4, true, [1, 10, 10, 8]);
    assert!(worst < 1e-5, "{worst}");
}

#[test]
fn a_map_smaller_than_the_window_is_one_window_on_both_paths() {
    // 3 x 5 with window 8: one 3 x 3 window side, no shift, the bias table of the window of 8.
    let worst = block_difference(8, 2, 8, true, [1, 3, 5, 8]);
    assert!(worst < 1e-5, "{worst}");
}
