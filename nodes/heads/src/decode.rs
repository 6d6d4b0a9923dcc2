//! From the heads' maps to agents: a cell is a detection where its class's heatmap is a local
//! maximum over its 3×3 neighbours (CenterPoint's max-pool NMS) and scores at least
//! `min_score`; the best `max_detections` are kept, each with its box and modes read at its
//! cell.

use bevworld_types::{BevGrid, DetectedAgent, TrajectoryMode};

use crate::config::DetectorConfig;

/// One frame's maps as plain values (the batch's item), read on the host.
pub struct FrameMaps<'a> {
    /// Heatmap logits, `[classes, H, W]`.
    pub heatmap: &'a [f32],
    /// `[BOX_CHANNELS, H, W]`.
    pub boxes: &'a [f32],
    /// `[K·(2T + 1), H, W]`.
    pub motion: &'a [f32],
}

fn sigmoid(x: f32) -> f64 {
    1.0 / (1.0 + (-f64::from(x)).exp())
}

fn softmax(logits: &[f64]) -> Vec<f64> {
    let max = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let exps: Vec<f64> = logits.iter().map(|l| (l - max).exp()).collect();
    let sum: f64 = exps.iter().sum();
    exps.iter().map(|e| e / sum).collect()
}

impl DetectorConfig {
    /// The agents in one frame's maps, best first, in the frame's ego frame.
    pub fn decode(&self, grid: &BevGrid, maps: &FrameMaps) -> Vec<DetectedAgent> {
        let (h, w) = (grid.height, grid.width);
        let plane = h * w;
        let mut peaks: Vec<(f32, usize, usize)> = Vec::new();
        let threshold = self.min_score;
        for class in 0..self.classes.len() {
            let heat = &maps.heatmap[class * plane..(class + 1) * plane];
            for i in 0..h {
                for j in 0..w {
                    let value = heat[i * w + j];
                    if !value.is_finite() || sigmoid(value) < threshold {
                        continue;
                    }
                    let mut is_peak = true;
                    'neighbours: for ii in i.saturating_sub(1)..(i + 2).min(h) {
                        for jj in j.saturating_sub(1)..(j + 2).min(w) {
                            let other = heat[ii * w + jj];
                            // Ties go to the first cell in row-major order.
                            if other > value || (other == value && ii * w + jj < i * w + j) {
                                is_peak = false;
                                break 'neighbours;
                            }
                        }
                    }
                    if is_peak {
                        peaks.push((value, class, i * w + j));
                    }
                }
            }
        }
        peaks.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.2.cmp(&b.2)));
        peaks.truncate(self.max_detections);
        peaks
            .into_iter()
            .map(|(logit, class, cell)| self.agent_at(grid, maps, class, cell, sigmoid(logit)))
            .collect()
    }

    fn agent_at(
        &self,
        grid: &BevGrid,
        maps: &FrameMaps,
        class: usize,
        cell: usize,
        score: f64,
    ) -> DetectedAgent {
        let plane = grid.height * grid.width;
        let at = |map: &[f32], channel: usize| f64::from(map[channel * plane + cell]);
        let (i, j) = (cell / grid.width, cell % grid.width);
        let resolution = f64::from(grid.resolution);
        let offset = |k: usize| at(maps.boxes, k).clamp(-0.5, 1.5);
        let x = f64::from(grid.x_range[0]) + (j as f64 + offset(0)) * resolution;
        let y = f64::from(grid.y_range[0]) + (i as f64 + offset(1)) * resolution;
        // exp of a log size: bounded, so that an untrained head gives finite, positive boxes.
        let size = |k: usize| at(maps.boxes, k).clamp(-5.0, 5.0).exp();
        let (k, t) = (self.motion.modes, self.motion.steps);
        let logits: Vec<f64> = (0..k).map(|m| at(maps.motion, k * 2 * t + m)).collect();
        let mut modes: Vec<TrajectoryMode> = softmax(&logits)
            .into_iter()
            .enumerate()
            .map(|(m, probability)| TrajectoryMode {
                probability,
                positions: (0..t)
                    .map(|s| {
                        let base = m * 2 * t + 2 * s;
                        [x + at(maps.motion, base), y + at(maps.motion, base + 1)]
                    })
                    .collect(),
            })
            .collect();
        modes.sort_by(|a, b| b.probability.total_cmp(&a.probability));
        DetectedAgent {
            detection_name: self.classes[class].clone(),
            score,
            centre: [x, y, at(maps.boxes, 2)],
            size: [size(3), size(4), size(5)],
            yaw: at(maps.boxes, 6).atan2(at(maps.boxes, 7)),
            velocity: [at(maps.boxes, 8), at(maps.boxes, 9)],
            modes,
        }
    }
}
