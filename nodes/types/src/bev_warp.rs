//! Moving a BEV grid by the ego's own motion: a planar rigid motion between two ego frames,
//! and a `[C, H, W]` map of one frame resampled into another, as if the world stood still.
//! The world model's ego-warp baseline and residual base, and the detector's two-frame input
//! (the previous frame's feature brought into the current frame), are this one warp.

use crate::EgoAction;
use crate::action::wrap_angle;
use crate::bev::BevGrid;
use crate::pose::{Pose, yaw_of};

/// A planar rigid motion: the pose of ego frame `b` in ego frame `a`'s coordinates
/// (`a_from_b`), read right to left.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PlanarMotion {
    pub x: f64,
    pub y: f64,
    pub yaw: f64,
}

impl PlanarMotion {
    /// `a_from_b = global_from_a⁻¹ · global_from_b`, projected onto the ground plane.
    pub fn between(global_from_a: &Pose, global_from_b: &Pose) -> Self {
        let a_from_b = global_from_a.inverse() * *global_from_b;
        Self {
            x: a_from_b.translation.x,
            y: a_from_b.translation.y,
            yaw: yaw_of(&a_from_b),
        }
    }

    /// The motion of one action: where the ego ends up, in the frame it started from.
    pub fn of_action(action: &EgoAction) -> Self {
        Self {
            x: action.dx,
            y: action.dy,
            yaw: action.dyaw,
        }
    }

    /// `a_from_c = a_from_b · b_from_c` (`self` is `a_from_b`).
    pub fn then(&self, b_from_c: &Self) -> Self {
        let (s, c) = self.yaw.sin_cos();
        Self {
            x: self.x + c * b_from_c.x - s * b_from_c.y,
            y: self.y + s * b_from_c.x + c * b_from_c.y,
            yaw: wrap_angle(self.yaw + b_from_c.yaw),
        }
    }

    /// `b_from_a` (`self` is `a_from_b`).
    pub fn inverse(&self) -> Self {
        let (s, c) = self.yaw.sin_cos();
        Self {
            x: -(c * self.x + s * self.y),
            y: s * self.x - c * self.y,
            yaw: wrap_angle(-self.yaw),
        }
    }

    /// Applies the motion to a point of frame `b`, giving it in frame `a`.
    pub fn apply(&self, point: [f64; 2]) -> [f64; 2] {
        let (s, c) = self.yaw.sin_cos();
        [
            self.x + c * point[0] - s * point[1],
            self.y + s * point[0] + c * point[1],
        ]
    }
}

/// Where a `[C, H, W]` latent lies: row i covers y from `y_range[0] + i·cell`, column j x from
/// `x_range[0] + j·cell` (the `BevGrid` layout).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LatentGrid {
    pub channels: usize,
    pub height: usize,
    pub width: usize,
    pub x_range: [f64; 2],
    pub y_range: [f64; 2],
}

impl LatentGrid {
    /// The grid of a `[channels, H, W]` map laid out on `grid`.
    pub fn of(grid: &BevGrid, channels: usize) -> Self {
        Self {
            channels,
            height: grid.height,
            width: grid.width,
            x_range: grid.x_range.map(f64::from),
            y_range: grid.y_range.map(f64::from),
        }
    }

    pub fn len(&self) -> usize {
        self.channels * self.height * self.width
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Metres per cell along x and y.
    pub fn cell_size(&self) -> [f64; 2] {
        [
            (self.x_range[1] - self.x_range[0]) / self.width as f64,
            (self.y_range[1] - self.y_range[0]) / self.height as f64,
        ]
    }

    /// The centre (x, y) of the cell in row `i`, column `j`, in metres.
    pub fn cell_centre(&self, i: usize, j: usize) -> [f64; 2] {
        let [cell_x, cell_y] = self.cell_size();
        [
            self.x_range[0] + (j as f64 + 0.5) * cell_x,
            self.y_range[0] + (i as f64 + 0.5) * cell_y,
        ]
    }
}

/// One cell's bilinear sample: up to four cells of the source map (row-major index in one
/// channel's plane) and their weights; corners outside the grid are left out, so the weights
/// sum to less than 1 near the edge.
pub type WarpTaps = Vec<(u32, f32)>;

/// Where each cell of `b` samples the map of `a` under `a_from_b`: every cell's centre moved
/// into `a` and read bilinearly (cell centres at integer coordinates). The same taps serve
/// every channel, and a differentiable warp (a gather and a weighted sum) as well as
/// `warp_latent`.
// -> one `WarpTaps` per cell of b, row-major [H * W]
pub fn warp_taps(grid: &LatentGrid, a_from_b: &PlanarMotion) -> Vec<WarpTaps> {
    let (h, w) = (grid.height, grid.width);
    let mut taps = Vec::with_capacity(h * w);
    for i in 0..h {
        for j in 0..w {
            taps.push(taps_at(grid, a_from_b.apply(grid.cell_centre(i, j))));
        }
    }
    taps
}

/// The bilinear taps of the map at `point` (metres, the grid's frame), cell centres at
/// integer coordinates; corners outside the grid are left out.
pub fn taps_at(grid: &LatentGrid, point: [f64; 2]) -> WarpTaps {
    let (h, w) = (grid.height, grid.width);
    let [cell_x, cell_y] = grid.cell_size();
    // Continuous cell coordinates, cell centres at integers.
    let u = (point[0] - grid.x_range[0]) / cell_x - 0.5;
    let v = (point[1] - grid.y_range[0]) / cell_y - 0.5;
    let (j0, i0) = (u.floor(), v.floor());
    let (fu, fv) = ((u - j0) as f32, (v - i0) as f32);
    let corners = [
        (i0, j0, (1.0 - fu) * (1.0 - fv)),
        (i0, j0 + 1.0, fu * (1.0 - fv)),
        (i0 + 1.0, j0, (1.0 - fu) * fv),
        (i0 + 1.0, j0 + 1.0, fu * fv),
    ];
    corners
        .iter()
        .filter(|&&(ci, cj, _)| ci >= 0.0 && cj >= 0.0 && ci < h as f64 && cj < w as f64)
        .map(|&(ci, cj, weight)| ((ci as usize * w + cj as usize) as u32, weight))
        .collect()
}

/// The latent of frame `a` seen from frame `b`: each cell of `b` takes the bilinear sample of
/// `latent_a` at its centre moved into `a` by `a_from_b` (`warp_taps`). Cells whose sample
/// falls outside `a`'s grid take `outside` (the standardised zero, the mean latent, for
/// standardised input), blended in where only some of the four neighbours are outside.
// latent_a: [C, H, W] -> [C, H, W]
pub fn warp_latent(
    latent_a: &[f32],
    grid: &LatentGrid,
    a_from_b: &PlanarMotion,
    outside: f32,
) -> Vec<f32> {
    let plane = grid.height * grid.width;
    let taps = warp_taps(grid, a_from_b);
    let mut out = vec![outside; grid.len()];
    for c in 0..grid.channels {
        let source = &latent_a[c * plane..(c + 1) * plane];
        for (cell, cell_taps) in taps.iter().enumerate() {
            let mut value = 0.0f32;
            let mut inside = 0.0f32;
            for &(index, weight) in cell_taps {
                value += weight * source[index as usize];
                inside += weight;
            }
            out[c * plane + cell] = value + (1.0 - inside) * outside;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DQuat, DVec3};

    fn grid() -> LatentGrid {
        LatentGrid {
            channels: 2,
            height: 4,
            width: 4,
            x_range: [-2.0, 2.0],
            y_range: [-2.0, 2.0],
        }
    }

    fn ramp() -> Vec<f32> {
        (0..32).map(|v| v as f32).collect()
    }

    #[test]
    fn standing_still_changes_nothing() {
        let out = warp_latent(&ramp(), &grid(), &PlanarMotion::default(), -9.0);
        assert_eq!(out, ramp());
    }

    #[test]
    fn driving_one_cell_forward_shifts_the_world_back_and_fills_the_new_edge() {
        // The ego moved 1 m (one cell) along +x: what was at x in `a` is at x − 1 in `b`, so
        // cell j of `b` reads cell j + 1 of `a`, and the last column comes from outside.
        let motion = PlanarMotion {
            x: 1.0,
            y: 0.0,
            yaw: 0.0,
        };
        let out = warp_latent(&ramp(), &grid(), &motion, -9.0);
        let a = ramp();
        for c in 0..2 {
            for i in 0..4 {
                for j in 0..3 {
                    assert_eq!(out[c * 16 + i * 4 + j], a[c * 16 + i * 4 + j + 1]);
                }
                assert_eq!(out[c * 16 + i * 4 + 3], -9.0);
            }
        }
    }

    #[test]
    fn a_quarter_turn_rotates_the_grid() {
        // b is a turned 90° left about the origin: b's +x axis is a's +y. Cell (i, j) of b at
        // (x, y) reads a at (−y, x).
        let motion = PlanarMotion {
            x: 0.0,
            y: 0.0,
            yaw: std::f64::consts::FRAC_PI_2,
        };
        let a = ramp();
        let out = warp_latent(&a, &grid(), &motion, -9.0);
        // b's cell (row 0, column 3) is at (1.5, −1.5) → a at (1.5, 1.5): row 3, column 3.
        assert!((out[3] - a[3 * 4 + 3]).abs() < 1e-4);
        // b's cell (row 3, column 0) is at (−1.5, 1.5) → a at (−1.5, −1.5): row 0, column 0.
        assert!((out[12] - a[0]).abs() < 1e-4);
    }

    #[test]
    fn motions_compose_like_poses() {
        let pose = |x: f64, y: f64, yaw: f64| {
            Pose::from_rotation_translation(DQuat::from_rotation_z(yaw), DVec3::new(x, y, 0.0))
        };
        let (g_a, g_b, g_c) = (
            pose(3.0, -1.0, 0.4),
            pose(5.0, 2.0, 1.1),
            pose(-2.0, 7.0, -2.5),
        );
        let a_b = PlanarMotion::between(&g_a, &g_b);
        let b_c = PlanarMotion::between(&g_b, &g_c);
        let a_c = PlanarMotion::between(&g_a, &g_c);
        let composed = a_b.then(&b_c);
        assert!((composed.x - a_c.x).abs() < 1e-9);
        assert!((composed.y - a_c.y).abs() < 1e-9);
        assert!((wrap_angle(composed.yaw - a_c.yaw)).abs() < 1e-9);
        // b_from_a · a_from_b is no motion at all, and b_from_a is what `between` gives.
        let identity = a_b.inverse().then(&a_b);
        assert!(identity.x.abs() < 1e-9 && identity.y.abs() < 1e-9 && identity.yaw.abs() < 1e-9);
        let b_a = PlanarMotion::between(&g_b, &g_a);
        let inverse = a_b.inverse();
        assert!((inverse.x - b_a.x).abs() < 1e-9 && (inverse.y - b_a.y).abs() < 1e-9);
        assert!(wrap_angle(inverse.yaw - b_a.yaw).abs() < 1e-9);
        let action = EgoAction::between(&g_a, 0, &g_b, 500_000).unwrap();
        let from_action = PlanarMotion::of_action(&action);
        assert!((from_action.x - a_b.x).abs() < 1e-9 && (from_action.y - a_b.y).abs() < 1e-9);
    }
}
