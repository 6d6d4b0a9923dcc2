//! The pillar feature net, its scatter, and the voxel lift: layouts against hand-computed
//! positions, the padding rule, and shapes at the tiny size and (by arithmetic) the paper's.

use bevworld_blocks::seeded_init;
use bevworld_blocks::swin::SwinConfig;
use bevworld_tokenizer::decoder::VoxelLiftConfig;
use bevworld_tokenizer::encoder::{PillarNetConfig, scatter_to_bev};
use bevworld_tokenizer::render::VoxelField;
use burn::prelude::*;

fn device() -> Device {
    Device::flex()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32")
}

#[test]
fn padded_point_slots_never_reach_the_pillar_feature() {
    let net = seeded_init(1, &device(), |d| PillarNetConfig::new(16).init(d));
    let real: Vec<f32> = (0..2 * 9).map(|i| (i as f32 * 0.37).sin() * 3.0).collect();
    let with_padding = |pad: f32| {
        let mut data = real.clone();
        data.extend(std::iter::repeat_n(pad, 9));
        let points = Tensor::<3>::from_data(TensorData::new(data, [1, 3, 9]), &device());
        let valid =
            Tensor::<2>::from_data(TensorData::new(vec![1.0f32, 1.0, 0.0], [1, 3]), &device());
        values(net.forward(points, valid))
    };
    let zeros = with_padding(0.0);
    assert_eq!(zeros.len(), 16);
    assert_eq!(with_padding(1000.0), zeros);
    assert_eq!(with_padding(-1000.0), zeros);
    // The max is over the real points only: order does not matter.
    let mut swapped = real[9..].to_vec();
    swapped.extend_from_slice(&real[..9]);
    swapped.extend(std::iter::repeat_n(0.0, 9));
    let points = Tensor::<3>::from_data(TensorData::new(swapped, [1, 3, 9]), &device());
    let valid = Tensor::<2>::from_data(TensorData::new(vec![1.0f32, 1.0, 0.0], [1, 3]), &device());
    assert_eq!(values(net.forward(points, valid)), zeros);
}

#[test]
fn scatter_puts_each_pillar_at_its_cell() {
    let (height, width) = (3, 4);
    // Two pillars, two channels: cell (iy 1, ix 2) = 6 and cell (2, 0) = 8.
    let features = Tensor::<2>::from_data(
        TensorData::new(vec![1.0f32, 2.0, 3.0, 4.0], [2, 2]),
        &device(),
    );
    let cells = Tensor::<1, Int>::from_data(TensorData::new(vec![6i64, 8], [2]), &device());
    let bev = scatter_to_bev(features, cells, height, width);
    assert_eq!(bev.dims(), [1, 2, 3, 4]);
    let v = values(bev);
    let at = |c: usize, y: usize, x: usize| v[(c * height + y) * width + x];
    assert_eq!((at(0, 1, 2), at(1, 1, 2)), (1.0, 2.0));
    assert_eq!((at(0, 2, 0), at(1, 2, 0)), (3.0, 4.0));
    assert_eq!(v.iter().filter(|&&x| x != 0.0).count(), 4);
}

#[test]
fn cell_blocks_land_at_their_voxels() {
    // The head's output, entry by entry: cell (y, x), then height, patch row, patch column and
    // feature. Each value is its own flat index, so the grid shows where each one went.
    let (c, z, r, rows, columns) = (2, 3, 2, 2, 3);
    let per_cell = z * r * r * c;
    let n = rows * columns * per_cell;
    let head = Tensor::<1, Int>::arange(0..n as i64, &device())
        .float()
        .reshape([1, rows, columns, per_cell]);
    let field = VoxelField::from_head(head, c, z, r);
    assert_eq!(field.shape.voxels(), [z, rows * r, columns * r]);
    let table = values(field.table().clone());
    let grid = field.to_grid();
    assert_eq!(grid.dims(), [1, c, z, rows * r, columns * r]);
    let v = values(grid);
    for y in 0..rows {
        for xx in 0..columns {
            for ci in 0..c {
                for zi in 0..z {
                    for ry in 0..r {
                        for rx in 0..r {
                            let source =
                                (y * columns + xx) * per_cell + ((zi * r + ry) * r + rx) * c + ci;
                            let (vy, vx) = (y * r + ry, xx * r + rx);
                            let target = ((ci * z + zi) * rows * r + vy) * columns * r + vx;
                            assert_eq!(v[target], source as f32);
                            // The table row of that voxel holds it, untouched.
                            let row = field.shape.row(vx, vy, zi);
                            assert_eq!(table[row * c + ci], source as f32);
                        }
                    }
                }
            }
        }
    }
    // A grid goes into a field and back unchanged.
    let back = VoxelField::from_grid(Tensor::<5>::from_data(
        TensorData::new(v.clone(), [1, c, z, rows * r, columns * r]),
        &device(),
    ));
    assert_eq!(values(back.to_grid()), v);
}

#[test]
fn voxel_lift_runs_at_a_small_size() {
    let config = VoxelLiftConfig::new(4, 32, [2, 2], [2, 2], 4, 4, 8, 2);
    let lift = seeded_init(2, &device(), |d| config.init(d));
    let voxels = lift.forward(Tensor::zeros([1, 4, 8, 8], &device()));
    assert_eq!(voxels.to_grid().dims(), [1, 4, 8, 32, 32]);
    assert_eq!(config.voxel_shape(8, 8), [4, 8, 32, 32]);
}

#[test]
fn paper_sizes_follow_the_papers_shape_chain() {
    // (4, 96, 96) -> (256, 96, 96) -> (128, 192, 192) -> (4096, 192, 192) -> (16, 64, 384, 384)
    let lift = VoxelLiftConfig::new(4, 256, [2, 2], [8, 4], 8, 16, 64, 2);
    assert_eq!(lift.block_channels(), 4096);
    assert_eq!(lift.voxel_shape(96, 96), [16, 64, 384, 384]);
    // Swin-T on the cameras: stride 32, 768 channels.
    let swin_t = SwinConfig::new(3, 4, 96, vec![2, 2, 6, 2], vec![3, 6, 12, 24], 7);
    assert!(swin_t.problems("image_backbone").is_empty());
    assert_eq!((swin_t.stride(), swin_t.out_channels()), (32, 768));
}
