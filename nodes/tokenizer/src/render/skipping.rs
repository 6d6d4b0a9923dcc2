//! Empty-space skipping and early ray termination, for inference.
//!
//! - **Occupancy.** α is evaluated once per voxel centre (one pass of the alpha head over the
//!   grid, shared by every ray of every view). A voxel is occupied when α > `alpha_threshold`.
//!   The occupied set is dilated by one voxel, because a trilinear sample reads the 8 voxels
//!   around it (unless `dilate: false`, which skips more and is no longer exact at surfaces'
//!   edges), and pooled into coarse cells of `cell³` voxels. A sample is kept when the
//!   coarse cell of its nearest voxel is occupied. Samples outside the grid read zero features,
//!   so they are kept only if α of the zero feature exceeds the threshold.
//! - **Early stop.** Kept samples go through the model in segments of `segment` per ray; after
//!   each, a ray whose transmittance fell below `stop_transmittance` is finished. On the CPU
//!   the fused renderer (`march`) evaluates them 16 at a time in one loop per ray, and checks
//!   after each 16.
//!
//! What is skipped is not exactly zero: α of an interpolated feature is not the interpolation
//! of α, and a stopped ray drops at most `stop_transmittance` of its weight. The error is
//! measured, not assumed (see `bench/results/tokenizer.md`). With `alpha_threshold < 0` and
//! `stop_transmittance = 0` nothing is skipped and the result equals the dense render.

use burn::prelude::*;
use burn::tensor::Bool;
use rayon::prelude::*;

use crate::render::batched::VoxelScene;
use crate::render::occupancy::{OccupancyGrid, SkipOptions, Skipping};
use crate::render::rays::{Rays, VoxelPlacement};
use crate::render::rendered::{RenderedRays, host_vec};
use crate::render::{log_transmittance_after, render_weights, sample_trilinear};

/// The logit padding samples get: α = σ(−1e4) = 0 and log(1 − α) = 0, exactly, in f32.
const PADDING_LOGIT: f32 = -1e4;

/// Building the grid from a voxel field: one pass of the alpha head over every voxel.
impl OccupancyGrid {
    /// Evaluates α at every voxel centre, a bounded number of table rows at a time.
    pub fn build(scene: &VoxelScene, options: &SkipOptions) -> Self {
        let (model, field) = (scene.model, &scene.voxels);
        let shape = field.shape;
        let (channels, [z, y, x]) = (shape.channels, shape.voxels());
        let device = field.device();
        // Compare logits with logit(threshold) rather than α with the threshold: a vectorised
        // sigmoid is accurate in absolute terms only (~1e-6 here), which would make every voxel
        // look occupied at small thresholds, while the logit is exact.
        let threshold = options.alpha_threshold;
        let threshold_logit = if threshold <= 0.0 {
            f32::NEG_INFINITY
        } else {
            (threshold / (1.0 - threshold)).ln()
        };
        let logits_of =
            |features: Tensor<3>| -> Vec<f32> { host_vec(model.alpha_logits(features)) };
        // Bound the [rows, C_v] intermediate to about 4 M values.
        let rows = shape.rows();
        let chunk = ((4 << 20) / channels.max(1)).clamp(1, rows.max(1));
        // By table row: on the CPU with the head's host weights (`AlphaHead::table_logits`), in
        // parallel over rows; elsewhere through the model, a bounded slab at a time.
        let by_row: Vec<bool> = match (model.alpha_head_on_host(), field.host_table()) {
            (Some(head), Some(table)) => head
                .table_logits(table, channels)
                .into_iter()
                .map(|s| s > threshold_logit)
                .collect(),
            _ => {
                let mut by_row = Vec::with_capacity(rows);
                for start in (0..rows).step_by(chunk) {
                    let count = chunk.min(rows - start);
                    let slab = field
                        .table()
                        .clone()
                        .narrow(0, start, count)
                        .reshape([1, count, channels]);
                    by_row.extend(logits_of(slab).into_iter().map(|s| s > threshold_logit));
                }
                by_row
            }
        };
        // Fine occupancy `[Z, Y, X]`, read from the table's row order through the per-axis
        // row terms (no integer division per voxel).
        let [x_terms, y_terms, z_terms] = shape.row_terms();
        let mut fine = Vec::with_capacity(z * y * x);
        for z_term in &z_terms {
            for y_term in &y_terms {
                fine.extend(
                    x_terms
                        .iter()
                        .map(|x_term| by_row[(z_term + y_term + x_term) as usize]),
                );
            }
        }
        let zero = Tensor::<3>::zeros([1, 1, channels], &device);
        let outside_occupied = logits_of(zero)
            .first()
            .is_some_and(|&s| s > threshold_logit);

        Self::from_fine(
            &fine,
            [z, y, x],
            options.cell,
            options.dilate,
            outside_occupied,
        )
    }
}

/// Rays per parallel task when listing kept samples.
const RAYS_PER_TASK: usize = 512;

/// The kept samples of every ray, flat: ray `r`'s are `start[r]..start[r + 1]`, in order
/// along the ray. One allocation for all rays (not one per ray), filled in parallel over
/// chunks of rays; the content does not depend on the split.
struct KeptSamples {
    start: Vec<usize>,
    positions: Vec<[f32; 3]>,
    depths: Vec<f32>,
}

impl KeptSamples {
    fn of(grid: &OccupancyGrid, rays: &Rays, depths: &[f32], placement: &VoxelPlacement) -> Self {
        let parts: Vec<KeptSamples> = rays
            .origins
            .par_chunks(RAYS_PER_TASK)
            .zip(rays.directions.par_chunks(RAYS_PER_TASK))
            .map(|(origins, directions)| {
                let mut part = KeptSamples {
                    start: Vec::with_capacity(origins.len() + 1),
                    positions: Vec::new(),
                    depths: Vec::new(),
                };
                part.start.push(0);
                for (o, d) in origins.iter().zip(directions) {
                    for &t in depths {
                        let p =
                            placement.to_voxel(std::array::from_fn(|axis| o[axis] + t * d[axis]));
                        if grid.keeps(p) {
                            part.positions.push(p);
                            part.depths.push(t);
                        }
                    }
                    part.start.push(part.positions.len());
                }
                part
            })
            .collect();
        let total = parts.iter().map(|part| part.positions.len()).sum();
        let mut kept = Self {
            start: Vec::with_capacity(rays.len() + 1),
            positions: Vec::with_capacity(total),
            depths: Vec::with_capacity(total),
        };
        kept.start.push(0);
        for part in parts {
            let offset = kept.positions.len();
            kept.start
                .extend(part.start.iter().skip(1).map(|&end| offset + end));
            kept.positions.extend(part.positions);
            kept.depths.extend(part.depths);
        }
        kept
    }

    fn count(&self, ray: usize) -> usize {
        self.start[ray + 1] - self.start[ray]
    }

    /// Up to `len` kept samples of `ray` from its `from`-th on.
    fn segment(&self, ray: usize, from: usize, len: usize) -> (&[[f32; 3]], &[f32]) {
        let begin = (self.start[ray] + from).min(self.start[ray + 1]);
        let end = (begin + len).min(self.start[ray + 1]);
        (&self.positions[begin..end], &self.depths[begin..end])
    }
}

impl VoxelScene<'_> {
    /// Renders `rays`, evaluating only kept samples and stopping opaque rays early.
    pub fn render_skipping(
        &self,
        grid: &OccupancyGrid,
        rays: &Rays,
        options: &SkipOptions,
    ) -> RenderedRays {
        let (model, voxels, depths, placement, chunk) = (
            self.model,
            &self.voxels,
            &self.depths,
            &self.placement,
            self.chunk,
        );
        let stop = if options.stop_transmittance > 0.0 {
            options.stop_transmittance.ln()
        } else {
            f32::NEG_INFINITY
        };
        if let Some(head) = model.alpha_head_on_host() {
            let skipping = Skipping {
                grid,
                stop_log_transmittance: stop,
            };
            if let Some(march) = self.march(&head, Some(skipping)) {
                return march.render(rays);
            }
        }
        let device = voxels.device();
        let channels = voxels.shape.channels;
        let r_count = rays.len();
        let kept = KeptSamples::of(grid, rays, depths, placement);
        let mut out = RenderedRays::zeros(r_count, channels, depths.len());
        let mut log_t = vec![0.0f32; r_count];
        let mut cursor = vec![0usize; r_count];
        let segment = options.segment.max(1);
        let mut active: Vec<usize> = (0..r_count).filter(|&r| kept.count(r) > 0).collect();
        while !active.is_empty() {
            for batch in active.chunks(chunk.max(1)) {
                let a = batch.len();
                let mut positions = Vec::with_capacity(a * segment);
                let mut sample_depths = Vec::with_capacity(a * segment);
                let mut padding = Vec::with_capacity(a * segment);
                let mut offsets = Vec::with_capacity(a);
                for &r in batch {
                    let (next_positions, next_depths) = kept.segment(r, cursor[r], segment);
                    let real = next_positions.len();
                    positions.extend_from_slice(next_positions);
                    sample_depths.extend_from_slice(next_depths);
                    padding.extend(std::iter::repeat_n(false, real));
                    positions.extend(std::iter::repeat_n([-1e3f32; 3], segment - real));
                    sample_depths.extend(std::iter::repeat_n(0.0f32, segment - real));
                    padding.extend(std::iter::repeat_n(true, segment - real));
                    out.samples_evaluated += real as u64;
                    offsets.push(log_t[r].exp());
                }
                let features = sample_trilinear(voxels, &positions).reshape([a, segment, channels]);
                let padding =
                    Tensor::<2, Bool>::from_data(TensorData::new(padding, [a, segment]), &device);
                let logits = model
                    .alpha_logits(features.clone())
                    .mask_fill(padding, PADDING_LOGIT); // [A, seg]
                let transmittance =
                    Tensor::<2>::from_data(TensorData::new(offsets, [a, 1]), &device);
                let weights = render_weights(logits.clone()) * transmittance; // [A, seg]
                let sample_depths =
                    Tensor::<2>::from_data(TensorData::new(sample_depths, [a, segment]), &device);
                let depth = host_vec((weights.clone() * sample_depths).sum_dim(1).reshape([a]));
                let feature = host_vec(
                    weights
                        .reshape([a, 1, segment])
                        .matmul(features)
                        .reshape([a * channels]),
                );
                let log_t_delta = host_vec(
                    log_transmittance_after(logits)
                        .narrow(1, segment - 1, 1)
                        .reshape([a]),
                );
                for (i, &r) in batch.iter().enumerate() {
                    out.depth[r] += depth[i];
                    for c in 0..channels {
                        out.features[r * channels + c] += feature[i * channels + c];
                    }
                    log_t[r] += log_t_delta[i];
                    cursor[r] += segment;
                }
            }
            active.retain(|&r| cursor[r] < kept.count(r) && log_t[r] >= stop);
        }
        let escape_depth = model.escape_depth();
        for ((opacity, depth), lt) in out.opacity.iter_mut().zip(&mut out.depth).zip(&log_t) {
            let transmittance = lt.exp();
            *opacity = 1.0 - transmittance;
            *depth += transmittance * escape_depth;
        }
        out
    }
}
