//! What the heads learn for one frame, from its annotated agents in the current ego frame:
//! CenterPoint's Gaussian heatmap per class, and at each agent's centre cell its box and
//! future trajectory.

use crate::config::{BOX_CHANNELS, DetectorConfig};
use bevworld_types::BevGrid;

/// One annotated agent in the current ego frame.
#[derive(Clone, Debug, PartialEq)]
pub struct AgentTruth {
    /// Index into the detector's classes.
    pub class: usize,
    /// Box centre, m.
    pub centre: [f64; 3],
    /// Width, length, height, m.
    pub size: [f64; 3],
    /// Heading about +z, rad.
    pub yaw: f64,
    /// Planar velocity, m/s; `None` where the dataset cannot tell it.
    pub velocity: Option<[f64; 2]>,
    /// The centre at each of the motion head's future steps, where annotated.
    pub future: Vec<Option<[f64; 2]>>,
}

/// One agent's regression targets, at its centre cell.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectTarget {
    /// Row-major cell of the output grid.
    pub cell: usize,
    pub class: usize,
    /// Offset in the cell (x, y), centre height, log width/length/height, sin and cos of the
    /// yaw, velocity (x, y).
    pub boxes: [f32; BOX_CHANNELS],
    pub velocity_known: bool,
    /// Future offsets from the centre, `[T]` of (x, y), and which are annotated.
    pub future: Vec<[f32; 2]>,
    pub future_known: Vec<bool>,
}

/// A frame's targets.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameTargets {
    /// `[classes, H, W]`, 1 exactly at each agent's centre cell.
    pub heatmap: Vec<f32>,
    pub objects: Vec<ObjectTarget>,
}

/// CenterNet's radius (Zhou et al. 2019, as CenterPoint uses it): the largest corner shift that
/// keeps a box of `length × width` cells at an IoU of at least `min_overlap`.
pub fn gaussian_radius(length: f64, width: f64, min_overlap: f64) -> f64 {
    let b1 = length + width;
    let c1 = width * length * (1.0 - min_overlap) / (1.0 + min_overlap);
    let r1 = (b1 + (b1 * b1 - 4.0 * c1).sqrt()) / 2.0;
    let b2 = 2.0 * (length + width);
    let c2 = (1.0 - min_overlap) * width * length;
    let r2 = (b2 + (b2 * b2 - 16.0 * c2).sqrt()) / 2.0;
    let a3 = 4.0 * min_overlap;
    let b3 = -2.0 * min_overlap * (length + width);
    let c3 = (min_overlap - 1.0) * width * length;
    let r3 = (b3 + (b3 * b3 - 4.0 * a3 * c3).sqrt()) / 2.0;
    r1.min(r2).min(r3)
}

/// CenterPoint's overlap for the radius.
pub const MIN_OVERLAP: f64 = 0.1;

/// Continuous cell coordinates of a point: column (x) and row (y), cell centres at `k + 0.5`.
pub fn cell_coordinates(grid: &BevGrid, x: f64, y: f64) -> (f64, f64) {
    let cell = f64::from(grid.resolution);
    (
        (x - f64::from(grid.x_range[0])) / cell,
        (y - f64::from(grid.y_range[0])) / cell,
    )
}

impl DetectorConfig {
    /// The targets of `agents` on the output grid; agents whose centre lies off the grid are
    /// left out.
    pub fn targets(&self, grid: &BevGrid, agents: &[AgentTruth]) -> FrameTargets {
        let (h, w) = (grid.height, grid.width);
        let cell_m = f64::from(grid.resolution);
        let mut heatmap = vec![0.0f32; self.classes.len() * h * w];
        let mut objects = Vec::new();
        for agent in agents {
            let (u, v) = cell_coordinates(grid, agent.centre[0], agent.centre[1]);
            let (j, i) = (u.floor(), v.floor());
            if !(j >= 0.0 && i >= 0.0 && j < w as f64 && i < h as f64)
                || agent.class >= self.classes.len()
            {
                continue;
            }
            let (j, i) = (j as usize, i as usize);
            let radius =
                gaussian_radius(agent.size[1] / cell_m, agent.size[0] / cell_m, MIN_OVERLAP)
                    .floor()
                    .max(self.min_radius as f64) as i64;
            draw_gaussian(
                &mut heatmap[agent.class * h * w..(agent.class + 1) * h * w],
                w,
                h,
                i,
                j,
                radius,
            );
            let velocity = agent.velocity.unwrap_or([0.0, 0.0]);
            let boxes = [
                (u - j as f64) as f32,
                (v - i as f64) as f32,
                agent.centre[2] as f32,
                agent.size[0].max(1e-3).ln() as f32,
                agent.size[1].max(1e-3).ln() as f32,
                agent.size[2].max(1e-3).ln() as f32,
                agent.yaw.sin() as f32,
                agent.yaw.cos() as f32,
                velocity[0] as f32,
                velocity[1] as f32,
            ];
            let steps = self.motion.steps;
            let mut future = vec![[0.0f32; 2]; steps];
            let mut future_known = vec![false; steps];
            for (k, position) in agent.future.iter().take(steps).enumerate() {
                if let Some([x, y]) = position {
                    future[k] = [(x - agent.centre[0]) as f32, (y - agent.centre[1]) as f32];
                    future_known[k] = true;
                }
            }
            objects.push(ObjectTarget {
                cell: i * w + j,
                class: agent.class,
                boxes,
                velocity_known: agent.velocity.is_some(),
                future,
                future_known,
            });
        }
        FrameTargets { heatmap, objects }
    }
}

/// Draws a Gaussian of `radius` cells (σ = (2r + 1) / 6) centred on cell (i, j), keeping the
/// larger value where it meets another.
fn draw_gaussian(plane: &mut [f32], w: usize, h: usize, i: usize, j: usize, radius: i64) {
    let sigma = (2 * radius + 1) as f64 / 6.0;
    for di in -radius..=radius {
        for dj in -radius..=radius {
            let (ii, jj) = (i as i64 + di, j as i64 + dj);
            if ii < 0 || jj < 0 || ii >= h as i64 || jj >= w as i64 {
                continue;
            }
            let value = (-((di * di + dj * dj) as f64) / (2.0 * sigma * sigma)).exp() as f32;
            let slot = &mut plane[ii as usize * w + jj as usize];
            *slot = slot.max(value);
        }
    }
}
