//! The LiDAR rays' termination loss: the negative log-likelihood of each return under the ray's
//! rendered termination distribution, its render weights (the line-of-sight supervision of
//! DS-NeRF and Urban Radiance Fields, on our fixed samples).
//!
//! Why: L1 on the expected depth `Σ w_i t_i` asks only for the mean of a ray's weights. A ray at
//! an object's edge meets it with half its weight on the object and half on the wall behind, and
//! its point floats in the gap. A LiDAR return says more than its depth's mean: the ray crossed
//! free space up to the return and stopped there. This term asks for exactly that distribution.
//!
//! The return at depth `d` between samples `t_i ≤ d < t_{i+1}` is spread over those two samples
//! in linear proportion (`q_i = (t_{i+1} − d) / (t_{i+1} − t_i)`, `q_{i+1} = 1 − q_i`), so that
//! the target's expected depth is `d` itself. A return before the first sample or beyond the last
//! puts all of it on that sample.

use burn::prelude::*;

/// The smallest weight the log sees: a ray whose target samples carry no weight at all costs
/// `−ln 1e-6 ≈ 13.8` instead of infinity, and its gradient stays finite.
const FLOOR: f32 = 1e-6;

/// Target termination distributions `[R, S]`, row-major, for returns at `ranges` along rays
/// sampled at the ascending `depths`.
pub fn termination_targets(depths: &[f32], ranges: &[f32]) -> Vec<f32> {
    let samples = depths.len();
    let mut targets = vec![0.0; ranges.len() * samples];
    if samples == 0 {
        return targets;
    }
    for (row, &range) in targets.chunks_mut(samples).zip(ranges) {
        // The first sample beyond the return.
        let after = depths.partition_point(|&t| t <= range);
        if after == 0 {
            row[0] = 1.0;
        } else if after == samples {
            row[samples - 1] = 1.0;
        } else {
            let (before, next) = (depths[after - 1], depths[after]);
            let to_next = ((next - range) / (next - before)).clamp(0.0, 1.0);
            row[after - 1] = to_next;
            row[after] = 1.0 - to_next;
        }
    }
    targets
}

/// Mean over rays of `−Σ_i q_i ln(w_i + 1e-6)`.
// weights [R, S], targets [R, S] -> [1]
pub fn termination_nll(weights: Tensor<2>, targets: Tensor<2>) -> Tensor<1> {
    let [rays, _] = weights.dims();
    (weights.add_scalar(FLOOR).log() * targets)
        .sum_dim(1)
        .neg()
        .reshape([rays])
        .mean()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(values: Vec<f32>, rows: usize) -> Tensor<2> {
        let columns = values.len() / rows;
        Tensor::from_data(TensorData::new(values, [rows, columns]), &Device::flex())
    }

    #[test]
    fn a_return_is_split_between_the_samples_around_it() {
        let depths = [1.0, 2.0, 4.0, 8.0];
        // 3 m: a half of the way from 2 to 4 m; 1 m exactly: all on the first sample; before
        // the first and beyond the last: clamped to them.
        let targets = termination_targets(&depths, &[3.0, 1.0, 0.5, 9.0, 7.0]);
        assert_eq!(
            targets,
            vec![
                0.0, 0.5, 0.5, 0.0, //
                1.0, 0.0, 0.0, 0.0, //
                1.0, 0.0, 0.0, 0.0, //
                0.0, 0.0, 0.0, 1.0, //
                0.0, 0.0, 0.25, 0.75,
            ]
        );
        // Each target's expected depth is its return's, where the samples reach it.
        for (row, range) in [(0, 3.0), (1, 1.0), (4, 7.0)] {
            let q = &targets[row * 4..(row + 1) * 4];
            let mean: f32 = q.iter().zip(depths).map(|(q, t)| q * t).sum();
            assert!((mean - range).abs() < 1e-6, "row {row}: {mean}");
        }
    }

    #[test]
    fn hand_computed_likelihoods() {
        // The weights equal to the target: −(½ ln ½ + ½ ln ½) = ln 2 (plus the floor's share).
        let q = tensor(vec![0.0, 0.5, 0.5, 0.0], 1);
        let at_target = termination_nll(tensor(vec![0.0, 0.5, 0.5, 0.0], 1), q.clone());
        assert!((at_target.into_scalar::<f32>() - std::f32::consts::LN_2).abs() < 1e-5);
        // All the weight on the first sample: the floor, −ln 1e-6, on both target samples.
        let early = termination_nll(tensor(vec![1.0, 0.0, 0.0, 0.0], 1), q.clone());
        assert!((early.into_scalar::<f32>() - 13.815_511).abs() < 1e-3);
        // A transparent ray costs as much; a ray that stops on one of the two samples is between.
        let half = termination_nll(tensor(vec![0.0, 1.0, 0.0, 0.0], 1), q);
        let expected = 0.5 * 13.815_511 - 0.5 * (1.0f32 + 1e-6).ln();
        assert!((half.into_scalar::<f32>() - expected).abs() < 1e-3);
    }

    #[test]
    fn the_target_distribution_is_the_best_one() {
        // Gibbs' inequality: among distributions, the target itself minimises the loss.
        let q = vec![0.0, 0.3, 0.7, 0.0];
        let best: f32 = termination_nll(tensor(q.clone(), 1), tensor(q.clone(), 1)).into_scalar();
        for other in [
            vec![0.0, 0.5, 0.5, 0.0],
            vec![0.1, 0.2, 0.7, 0.0],
            vec![0.0, 0.3, 0.6, 0.1],
        ] {
            let cost = termination_nll(tensor(other.clone(), 1), tensor(q.clone(), 1));
            let cost: f32 = cost.into_scalar();
            assert!(cost > best, "{other:?}");
        }
    }
}
