//! The distortion loss of Mip-NeRF 360 (Barron et al. 2022, eq. 15) on a ray's render weights:
//! `L = Σ_i Σ_j w_i w_j |s_i − s_j| + ⅓ Σ_i w_i² δ_i`.
//!
//! Why: the L1 depth loss fits the *expected* depth `Σ w_i t_i`, which a ray can match with its
//! weight spread over the foreground and the background behind it. Its point then floats in the
//! gap, and such edge rays carry most of a fitted frame's Chamfer. This term is smallest when a
//! ray's weight sits in one short interval, so it pulls each ray onto one surface.
//!
//! `s` is the sample's index normalised to [0, 1] (interval midpoints `(i + ½)/S`, widths
//! `δ = 1/S`): the samples are dense near the car and sparse far away, and metric distances
//! would make a far ray's spread cost many times a near one's.

use burn::prelude::*;

/// Mean distortion of the rays' weights. With `s` sorted, the double sum is
/// `2 Σ_i w_i (s_i W_<i − (ws)_<i)`, where `W_<i` and `(ws)_<i` are exclusive cumulative sums,
/// so the cost is linear in the samples.
// [R, S] -> [1]
pub fn distortion(weights: Tensor<2>) -> Tensor<1> {
    let [rays, samples] = weights.dims();
    let device = weights.device();
    let width = 1.0 / samples as f32;
    let midpoints: Vec<f32> = (0..samples).map(|i| (i as f32 + 0.5) * width).collect();
    let s = Tensor::<2>::from_data(TensorData::new(midpoints, [1, samples]), &device); // [1, S]
    let ws = weights.clone() * s.clone(); // [R, S]
    let weight_before = weights.clone().cumsum(1) - weights.clone(); // [R, S]
    let ws_before = ws.clone().cumsum(1) - ws.clone(); // [R, S]
    let between = (ws * weight_before - weights.clone() * ws_before)
        .sum_dim(1)
        .mul_scalar(2.0); // [R, 1]
    let within = weights.powi_scalar(2).sum_dim(1).mul_scalar(width / 3.0); // [R, 1]
    (between + within).reshape([rays]).mean()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn value(weights: Vec<f32>, rays: usize) -> f32 {
        let samples = weights.len() / rays;
        let w = Tensor::<2>::from_data(TensorData::new(weights, [rays, samples]), &Device::flex());
        distortion(w).into_scalar()
    }

    #[test]
    fn hand_computed_rays() {
        // Two samples, s = (0.25, 0.75), δ = 0.5.
        // All weight on one sample: ⅓ · 1 · 0.5 = 1/6.
        assert!((value(vec![1.0, 0.0], 1) - 1.0 / 6.0).abs() < 1e-6);
        // Split in half: 2 · 0.5 · 0.5 · 0.5 + ⅓ · (0.25 + 0.25) · 0.5 = 1/4 + 1/12 = 1/3.
        assert!((value(vec![0.5, 0.5], 1) - 1.0 / 3.0).abs() < 1e-6);
        // A transparent ray costs nothing; the mean over the two rays is 1/12.
        assert!((value(vec![0.0, 0.0, 1.0, 0.0], 2) - 1.0 / 12.0).abs() < 1e-6);
    }

    #[test]
    fn matches_the_double_sum() {
        let samples = 7;
        let weights: Vec<f32> = (0..3 * samples)
            .map(|k| ((k * 37 % 11) as f32 + 0.5) / 60.0)
            .collect();
        let mut expected = 0.0f64;
        for ray in weights.chunks(samples) {
            let s = |i: usize| (i as f64 + 0.5) / samples as f64;
            for i in 0..samples {
                for j in 0..samples {
                    expected += ray[i] as f64 * ray[j] as f64 * (s(i) - s(j)).abs();
                }
                expected += ray[i] as f64 * ray[i] as f64 / (3.0 * samples as f64);
            }
        }
        expected /= 3.0;
        let got = value(weights, 3) as f64;
        assert!((got - expected).abs() < 1e-6, "{got} vs {expected}");
    }

    #[test]
    fn a_concentrated_ray_costs_less_than_a_spread_one() {
        let mut near = vec![0.0; 48];
        near[10] = 0.9;
        let mut spread = vec![0.0; 48];
        spread[10] = 0.45;
        spread[30] = 0.45;
        assert!(value(near, 1) < value(spread, 1) / 10.0);
    }
}
