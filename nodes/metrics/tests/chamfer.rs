//! Chamfer distance against hand-computed values and its defining invariants.

use bevworld_metrics::{Roi, chamfer, chamfer_in_roi};

#[test]
fn identical_clouds_give_zero() {
    let cloud: Vec<[f64; 3]> = (0..500)
        .map(|k| [k as f64 * 0.3, (k % 7) as f64, (k % 3) as f64 * 0.5])
        .collect();
    assert_eq!(chamfer(&cloud, &cloud), 0.0);
}

#[test]
fn translation_by_d_gives_d_squared_for_a_single_point() {
    for d in [0.1, 1.0, 3.5] {
        assert!((chamfer(&[[1.0, 2.0, 3.0]], &[[1.0 + d, 2.0, 3.0]]) - d * d).abs() < 1e-12);
    }
}

#[test]
fn hand_computed_asymmetric_case() {
    // pred {(0,0,0), (2,0,0)}, gt {(0,0,0)}:
    // pred -> gt: 0 and 4, mean 2; gt -> pred: 0, mean 0; CD = (2 + 0) / 2 = 1.
    assert!((chamfer(&[[0.0; 3], [2.0, 0.0, 0.0]], &[[0.0; 3]]) - 1.0).abs() < 1e-12);
    // pred {(0,0,0)}, gt {(1,0,0), (0,3,0)}: pred -> gt 1; gt -> pred (1 + 9) / 2 = 5; CD = 3.
    assert!((chamfer(&[[0.0; 3]], &[[1.0, 0.0, 0.0], [0.0, 3.0, 0.0]]) - 3.0).abs() < 1e-12);
}

#[test]
fn nearest_neighbours_are_exact_on_a_dense_grid() {
    // A grid and the same grid shifted by (0.1, 0.2, 0): every nearest neighbour is the shifted
    // twin, so CD = 0.01 + 0.04 = 0.05 exactly (an approximate search would over-estimate).
    let grid: Vec<[f64; 3]> = (0..40)
        .flat_map(|i| (0..40).map(move |j| [i as f64, j as f64, 0.0]))
        .collect();
    let shifted: Vec<[f64; 3]> = grid
        .iter()
        .map(|p| [p[0] + 0.1, p[1] + 0.2, p[2]])
        .collect();
    assert!((chamfer(&grid, &shifted) - 0.05).abs() < 1e-12);
}

#[test]
fn an_empty_side_gives_zero_as_4d_occ_defines_it() {
    assert_eq!(chamfer(&[], &[[1.0, 0.0, 0.0]]), 0.0);
    // Everything predicted lies outside the ROI: 0, with the counts after the ROI.
    let result = chamfer_in_roi(&[[100.0, 0.0, 0.0]], &[[1.0, 0.0, 0.0]], &Roi::FOUR_D_OCC);
    assert_eq!(
        (result.chamfer, result.pred_points, result.gt_points),
        (0.0, 0, 1)
    );
}

#[test]
fn roi_is_inclusive_and_applied_to_each_cloud() {
    let roi = Roi::FOUR_D_OCC;
    assert!(
        roi.contains(&[70.0, -70.0, 4.5])
            && !roi.contains(&[70.0001, 0.0, 0.0])
            && !roi.contains(&[0.0, 0.0, -4.6])
    );
    // The far predicted point is dropped before matching: it would otherwise dominate.
    let result = chamfer_in_roi(&[[0.0; 3], [200.0, 0.0, 0.0]], &[[0.5, 0.0, 0.0]], &roi);
    assert_eq!((result.pred_points, result.gt_points), (1, 1));
    assert!((result.chamfer - 0.25).abs() < 1e-12);
    assert_eq!(Roi::preset("vidar"), Some(Roi::VIDAR));
    assert!(Roi::VIDAR.contains(&[51.2, -51.2, 3.0]) && !Roi::VIDAR.contains(&[0.0, 0.0, 3.1]));
    assert_eq!(Roi::preset("waymo"), None);
}
