//! Rendering on the CPU as one fused kernel per chunk of rays: each ray's samples are placed,
//! sampled trilinearly, run through the alpha head, weighted and summed in buffers the size of
//! one ray, with nothing written to memory but the ray's results.
//!
//! The tensor path (`Tokenizer::render_rays`, kept for training and for other devices) writes
//! every sample's features `[R·S, C_v]`, the head's hidden layer `[R·S, H]` and the weights
//! `[R, S]` to memory and reads them back, op after op; at the tiny size that traffic, and the
//! skinny matmuls of an 8 → 16 → 1 head, cost more than the arithmetic. Here a ray's features
//! stay in a `[C_v, S]` buffer (channels as rows, so that the head's loops run along the
//! samples and vectorise), and empty-space skipping and early stop are branches in the same
//! loop rather than bookkeeping around batches of segments.
//!
//! The arithmetic is the tensor path's: `α = σ(s)` with `s = w₂ · relu(W₁ f + b₁) + b₂`,
//! `w_i = exp(log σ(s_i) + Σ_{j<i} log σ(−s_j))` (log space, never a product of small
//! numbers), depth `Σ w_i t_i`, feature `Σ w_i f_i`. Sums run in another order than burn's, so
//! results agree to rounding (tested against the tensor path).

use bevworld_blocks::fast_math::{exp, log_sigmoid_pair};
use bevworld_blocks::host::vectorized;
use rayon::prelude::*;

use crate::render::field::FieldShape;
use crate::render::occupancy::Skipping;
use crate::render::rays::{Rays, VoxelPlacement};
use crate::render::rendered::RenderedRays;
use crate::render::trilinear::sample_point;

/// The alpha head's weights on the host: `s = w₂ · relu(W₁ f + b₁) + b₂`.
#[derive(Clone, Debug, PartialEq)]
pub struct AlphaHead {
    /// `W₁` as burn stores it, `[C_v, H]` row-major.
    pub hidden_weight: Vec<f32>,
    pub hidden_bias: Vec<f32>,
    /// `w₂`, `[H]`.
    pub out_weight: Vec<f32>,
    pub out_bias: f32,
}

impl AlphaHead {
    fn hidden(&self) -> usize {
        self.hidden_bias.len()
    }

    /// The logits of `BLOCK` features given channel by channel (`features[c][s]`), vectorised
    /// along the samples.
    #[inline(always)]
    fn block_logits(&self, features: &[[f32; BLOCK]]) -> [f32; BLOCK] {
        let hidden = self.hidden();
        let mut logits = [self.out_bias; BLOCK];
        for k in 0..hidden {
            let mut h = [self.hidden_bias[k]; BLOCK];
            for (c, row) in features.iter().enumerate() {
                let w = self.hidden_weight[c * hidden + k];
                for (v, &f) in h.iter_mut().zip(row) {
                    *v += f * w;
                }
            }
            let w = self.out_weight[k];
            for (l, &v) in logits.iter_mut().zip(&h) {
                *l += v.max(0.0) * w;
            }
        }
        logits
    }

    /// The logit of every row of a `[rows, C_v]` table (the occupancy grid's α at each voxel
    /// centre), in parallel over chunks of rows.
    pub fn table_logits(&self, table: &[f32], channels: usize) -> Vec<f32> {
        let rows = table.len() / channels.max(1);
        let mut logits = vec![0f32; rows];
        if channels == 0 {
            return logits;
        }
        const ROWS_PER_TASK: usize = 4096;
        logits
            .par_chunks_mut(ROWS_PER_TASK)
            .zip(table.par_chunks(ROWS_PER_TASK * channels))
            .for_each(|(logits, table)| {
                vectorized(TableKernel {
                    head: self,
                    channels,
                    table,
                    logits,
                })
            });
        logits
    }
}

struct TableKernel<'a> {
    head: &'a AlphaHead,
    channels: usize,
    table: &'a [f32],
    logits: &'a mut [f32],
}

impl macerator::WithSimd for TableKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) {
        let channels = self.channels;
        let mut features = vec![[0f32; BLOCK]; channels];
        for (logits, rows) in self
            .logits
            .chunks_mut(BLOCK)
            .zip(self.table.chunks(BLOCK * channels))
        {
            for (s, row) in rows.chunks_exact(channels).enumerate() {
                for (feature, &v) in features.iter_mut().zip(row) {
                    feature[s] = v;
                }
            }
            let block = self.head.block_logits(&features);
            logits.copy_from_slice(&block[..logits.len()]);
        }
    }
}

/// Samples evaluated together: one AVX-512 register of logits. Small enough that a stopped ray
/// wastes little, large enough that the head's loops run full vectors.
const BLOCK: usize = 16;

/// Everything a march reads.
pub struct March<'a> {
    pub shape: FieldShape,
    pub table: &'a [f32],
    pub head: &'a AlphaHead,
    pub depths: &'a [f32],
    pub placement: VoxelPlacement,
    /// The depth a ray's remaining transmittance adds (`Tokenizer::escape_depth`).
    pub escape_depth: f32,
    pub skipping: Option<Skipping<'a>>,
}

/// Rays per parallel task.
const RAYS_PER_TASK: usize = 64;

impl March<'_> {
    /// Renders every ray. Opacity is `Σ w_i` for a dense march and `1 − T` for a skipping one,
    /// as the two tensor paths define it.
    pub fn render(&self, rays: &Rays) -> RenderedRays {
        let channels = self.shape.channels;
        let count = rays.len();
        let mut out = RenderedRays::zeros(count, channels, self.depths.len());
        let terms = self.shape.row_terms();
        let evaluated: u64 = out
            .features
            .par_chunks_mut(RAYS_PER_TASK * channels.max(1))
            .zip(out.depth.par_chunks_mut(RAYS_PER_TASK))
            .zip(out.opacity.par_chunks_mut(RAYS_PER_TASK))
            .zip(rays.origins.par_chunks(RAYS_PER_TASK))
            .zip(rays.directions.par_chunks(RAYS_PER_TASK))
            .map(|((((features, depth), opacity), origins), directions)| {
                vectorized(RayKernel {
                    march: self,
                    terms: &terms,
                    origins,
                    directions,
                    features,
                    depth,
                    opacity,
                })
            })
            .sum();
        out.samples_evaluated = evaluated;
        out
    }
}

struct RayKernel<'a> {
    march: &'a March<'a>,
    terms: &'a [Vec<i64>; 3],
    origins: &'a [[f32; 3]],
    directions: &'a [[f32; 3]],
    features: &'a mut [f32],
    depth: &'a mut [f32],
    opacity: &'a mut [f32],
}

impl macerator::WithSimd for RayKernel<'_> {
    /// Samples evaluated.
    type Output = u64;

    #[inline(always)]
    fn with_simd<S: macerator::Simd>(self) -> u64 {
        let m = self.march;
        let channels = m.shape.channels;
        let [depth_voxels, height, width] = m.shape.voxels();
        let sizes = [width as f32, height as f32, depth_voxels as f32];
        let samples = m.depths.len();
        let stop = m
            .skipping
            .map_or(f32::NEG_INFINITY, |s| s.stop_log_transmittance);
        // One ray's kept samples: positions, depths, features [C_v, n], logits and weights.
        let mut positions: Vec<[f32; 3]> = Vec::with_capacity(samples);
        let mut kept_depths: Vec<f32> = Vec::with_capacity(samples);
        let mut point = vec![0f32; channels];
        // A block's features, one row of `BLOCK` samples per channel: fixed-size rows, so that
        // every loop below is whole vectors with no tail.
        let mut features = vec![[0f32; BLOCK]; channels];
        let mut evaluated = 0u64;
        for (ray, (o, d)) in self.origins.iter().zip(self.directions).enumerate() {
            positions.clear();
            kept_depths.clear();
            for &t in m.depths {
                let p = m
                    .placement
                    .to_voxel(std::array::from_fn(|axis| o[axis] + t * d[axis]));
                if m.skipping.is_none_or(|s| s.grid.keeps(p)) {
                    positions.push(p);
                    kept_depths.push(t);
                }
            }
            let ray_features = &mut self.features[ray * channels..(ray + 1) * channels];
            let (mut depth, mut weight_sum, mut log_t) = (0f32, 0f32, 0f32);
            for (block, block_depths) in positions.chunks(BLOCK).zip(kept_depths.chunks(BLOCK)) {
                let n = block.len();
                evaluated += n as u64;
                for row in features.iter_mut() {
                    *row = [0.0; BLOCK];
                }
                for (s, &p) in block.iter().enumerate() {
                    point.iter_mut().for_each(|v| *v = 0.0);
                    sample_point(m.table, self.terms, sizes, channels, p, &mut point);
                    for (row, &v) in features.iter_mut().zip(&point) {
                        row[s] = v;
                    }
                }
                let logits = m.head.block_logits(&features);
                let mut log_alpha = [0f32; BLOCK];
                let mut log_transparency = [0f32; BLOCK];
                for ((a, t), &s) in log_alpha.iter_mut().zip(&mut log_transparency).zip(&logits) {
                    (*a, *t) = log_sigmoid_pair(s);
                }
                // Weights: the running log transmittance is the one sequential step; samples
                // past `n` (a block's padding) weigh nothing and leave it unchanged.
                let mut weights = [0f32; BLOCK];
                for ((w, &a), &t) in weights
                    .iter_mut()
                    .zip(&log_alpha)
                    .zip(&log_transparency)
                    .take(n)
                {
                    *w = a + log_t;
                    log_t += t;
                }
                for w in weights.iter_mut() {
                    *w = exp(*w);
                }
                for w in weights.iter_mut().skip(n) {
                    *w = 0.0;
                }
                for (&w, &t) in weights.iter().zip(block_depths) {
                    depth += w * t;
                    weight_sum += w;
                }
                for (acc, row) in ray_features.iter_mut().zip(&features) {
                    for (&w, &f) in weights.iter().zip(row).take(n) {
                        *acc += w * f;
                    }
                }
                if log_t < stop {
                    break;
                }
            }
            let opacity = if m.skipping.is_some() {
                1.0 - exp(log_t)
            } else {
                weight_sum
            };
            self.depth[ray] = depth + (1.0 - opacity) * m.escape_depth;
            self.opacity[ray] = opacity;
        }
        evaluated
    }
}
