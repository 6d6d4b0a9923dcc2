//! The Fréchet distance maths, on its own, against closed forms.

use bevworld_metrics::frechet::{sqrt_psd, symmetric_eigen};
use bevworld_metrics::{GaussianStats, frechet_distance};

fn stats(mean: Vec<f64>, covariance: Vec<f64>) -> GaussianStats {
    GaussianStats {
        mean,
        covariance,
        count: 100,
    }
}

#[test]
fn identical_distributions_are_at_distance_zero() {
    let s = stats(
        vec![1.0, -2.0, 0.5],
        vec![2.0, 0.3, 0.1, 0.3, 1.0, -0.2, 0.1, -0.2, 0.5],
    );
    assert!(frechet_distance(&s, &s).unwrap().abs() < 1e-10);
}

#[test]
fn shifted_means_add_their_squared_distance() {
    let cov = vec![1.5, 0.2, 0.2, 0.7];
    let a = stats(vec![0.0, 0.0], cov.clone());
    let b = stats(vec![3.0, 4.0], cov);
    assert!((frechet_distance(&a, &b).unwrap() - 25.0).abs() < 1e-9);
}

#[test]
fn diagonal_covariances_match_the_closed_form() {
    // For diagonal S1, S2: Tr(S1 + S2 - 2 sqrt(S1 S2)) = sum (sqrt(s1) - sqrt(s2))^2.
    let a = stats(
        vec![0.0; 3],
        vec![4.0, 0.0, 0.0, 0.0, 9.0, 0.0, 0.0, 0.0, 1.0],
    );
    let b = stats(
        vec![0.0; 3],
        vec![1.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 1.0],
    );
    let expected = (2.0f64 - 1.0).powi(2) + (3.0f64 - 2.0).powi(2);
    assert!((frechet_distance(&a, &b).unwrap() - expected).abs() < 1e-9);
}

#[test]
fn scaled_covariance_closed_form() {
    // S2 = k^2 S1 gives Tr(S1)(1 - k)^2, for any (non-diagonal) S1.
    let s1 = vec![2.0, 0.5, 0.3, 0.5, 1.5, -0.4, 0.3, -0.4, 1.0];
    let k = 3.0;
    let s2: Vec<f64> = s1.iter().map(|v| v * k * k).collect();
    let expected = (2.0 + 1.5 + 1.0) * (1.0f64 - k).powi(2);
    let d = frechet_distance(&stats(vec![0.0; 3], s1), &stats(vec![0.0; 3], s2)).unwrap();
    assert!((d - expected).abs() < 1e-8, "{d} vs {expected}");
}

#[test]
fn eigen_and_square_root_are_exact_to_round_off() {
    let m = vec![4.0, 1.0, 0.5, 1.0, 3.0, 0.2, 0.5, 0.2, 2.0];
    let (values, vectors) = symmetric_eigen(&m, 3);
    // A v = lambda v for every pair.
    for k in 0..3 {
        for i in 0..3 {
            let av: f64 = (0..3).map(|j| m[i * 3 + j] * vectors[j * 3 + k]).sum();
            assert!((av - values[k] * vectors[i * 3 + k]).abs() < 1e-12);
        }
    }
    let root = sqrt_psd(&m, 3);
    for i in 0..3 {
        for j in 0..3 {
            let squared: f64 = (0..3).map(|k| root[i * 3 + k] * root[k * 3 + j]).sum();
            assert!((squared - m[i * 3 + j]).abs() < 1e-12);
        }
    }
}

#[test]
fn fitting_matches_numpy_cov_and_rejects_bad_input() {
    let rows = vec![vec![1.0, 2.0], vec![3.0, 6.0], vec![5.0, 7.0]];
    let fitted = GaussianStats::fit(&rows).unwrap();
    assert_eq!(fitted.mean, vec![3.0, 5.0]);
    // np.cov([[1, 3, 5], [2, 6, 7]]) = [[4, 5], [5, 7]].
    assert_eq!(fitted.covariance, vec![4.0, 5.0, 5.0, 7.0]);
    assert!(
        GaussianStats::fit(&rows[..1])
            .unwrap_err()
            .to_string()
            .contains("at least 2")
    );
    assert!(GaussianStats::fit(&[vec![1.0], vec![1.0, 2.0]]).is_err());
    assert!(GaussianStats::fit(&[vec![f64::NAN], vec![1.0]]).is_err());
    let other = stats(vec![0.0; 3], vec![1.0; 9]);
    assert!(
        frechet_distance(&fitted, &other)
            .unwrap_err()
            .to_string()
            .contains("dimensions differ")
    );
}

/// Deterministic pseudo-random rows.
fn rows(count: usize, dim: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut state = seed
        .wrapping_mul(6364136223846793005)
        .wrapping_add(1442695040888963407);
    (0..count)
        .map(|_| {
            (0..dim)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
                })
                .collect()
        })
        .collect()
}

#[test]
fn low_rank_route_agrees_with_the_full_decomposition() {
    use bevworld_metrics::frechet::frechet_distance_of_features;
    // Fewer samples than dimensions (the low-rank route), both ways round.
    for (n1, n2) in [(4, 6), (7, 3), (5, 5)] {
        let a = rows(n1, 9, 1 + n1 as u64);
        let b: Vec<Vec<f64>> = rows(n2, 9, 100 + n2 as u64)
            .into_iter()
            .map(|r| r.into_iter().map(|v| 0.5 * v + 0.3).collect())
            .collect();
        let full = frechet_distance(
            &GaussianStats::fit(&a).unwrap(),
            &GaussianStats::fit(&b).unwrap(),
        )
        .unwrap();
        let low_rank = frechet_distance_of_features(&a, &b).unwrap();
        // The full route takes square roots of the rank-deficient product's round-off
        // eigenvalues (~1e-16, whose roots are ~1e-8); the low-rank route never sees them.
        assert!(
            (full - low_rank).abs() <= 1e-7 * (1.0 + full),
            "{n1} x {n2}: full {full} vs low rank {low_rank}"
        );
        assert!(frechet_distance_of_features(&a, &a).unwrap().abs() < 1e-9);
    }
    // More samples than dimensions takes the full route and still agrees with itself.
    let (a, b) = (rows(20, 3, 5), rows(15, 3, 6));
    let full = frechet_distance(
        &GaussianStats::fit(&a).unwrap(),
        &GaussianStats::fit(&b).unwrap(),
    )
    .unwrap();
    assert_eq!(frechet_distance_of_features(&a, &b).unwrap(), full);
    assert!(frechet_distance_of_features(&a, &rows(4, 2, 1)).is_err());
    assert!(frechet_distance_of_features(&a[..1], &b).is_err());
}
