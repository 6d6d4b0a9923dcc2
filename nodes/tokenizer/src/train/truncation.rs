//! Training renders each drawn LiDAR ray only as far as its return needs
//! (`rays.lidar_samples_past_return`): the samples behind an opaque surface carry no weight,
//! and most of a sweep's returns are near, so most of a ray's fixed samples lie behind them.
//! Rays of similar need are rendered together, since one render takes one sample count.

/// Rays rendered together to the same number of samples.
#[derive(Clone, Debug, PartialEq)]
pub struct TruncatedGroup {
    /// Indices into the frame's in-range LiDAR rays.
    pub rays: Vec<usize>,
    /// Samples rendered: enough for the group's farthest return and `past` beyond it.
    pub samples: usize,
}

/// Groups a step's LiDAR rays by how many samples each needs: those up to its return and
/// `past` beyond it, at most all of them. The rays are sorted by that count (stably, so the
/// grouping is a function of the draw) and cut into at most `TRUNCATED_GROUPS` groups of
/// equal size, each rendered to its longest ray's count: a handful of renders instead of one
/// per ray, and each ray wastes few samples.
pub fn truncated_groups(
    chosen: &[usize],
    ranges: &[f32],
    depths: &[f32],
    past: usize,
) -> Vec<TruncatedGroup> {
    let needed = |range: f32| {
        let before = depths.partition_point(|&t| t <= range);
        (before + past).clamp(1, depths.len())
    };
    let mut rays: Vec<(usize, usize)> = chosen.iter().map(|&i| (needed(ranges[i]), i)).collect();
    rays.sort_by_key(|&(samples, _)| samples);
    let size = rays.len().div_ceil(TRUNCATED_GROUPS).max(1);
    rays.chunks(size)
        .map(|chunk| TruncatedGroup {
            rays: chunk.iter().map(|&(_, i)| i).collect(),
            samples: chunk.iter().map(|&(samples, _)| samples).max().unwrap_or(1),
        })
        .collect()
}

/// How many renders a step's truncated LiDAR rays take at most.
pub const TRUNCATED_GROUPS: usize = 4;
