//! Pillarization on hand-computed cases, hard cases, and against the dense reference.

use bevworld_pillarize::dense::pillarize_dense;
use bevworld_pillarize::{Limits, Pillarizer};
use bevworld_types::{PILLAR_FEATURES, PillarGrid, Pillars};

/// A 4 x 4 grid of 1 m pillars over [0, 4) x [0, 4) x [-1, 1).
fn small() -> PillarGrid {
    PillarGrid {
        x_range: [0.0, 4.0],
        y_range: [0.0, 4.0],
        z_range: [-1.0, 1.0],
        pillar_size: 1.0,
    }
}

fn run(grid: PillarGrid, limits: Limits, points: &[[f32; 4]]) -> Pillars {
    let sparse = Pillarizer::new(grid, limits).run(points);
    let dense = pillarize_dense(&grid, limits, points);
    assert_eq!(
        sparse.coords, dense.coords,
        "sparse and dense disagree on pillars"
    );
    assert_eq!(sparse.point_counts, dense.point_counts);
    assert_eq!(sparse.features, dense.features);
    assert_eq!(sparse.stats, dense.stats);
    let s = sparse.stats;
    assert_eq!(s.points_in, s.accounted(), "every point is accounted for");
    sparse
}

#[test]
fn hand_computed_features() {
    // Two points in pillar (ix 1, iy 2): centre (1.5, 2.5); mean (1.2, 2.4, 0.3).
    let points = [[1.0, 2.2, 0.2, 5.0], [1.4, 2.6, 0.4, 7.0]];
    let pillars = run(small(), Limits::default(), &points);
    assert_eq!(pillars.len(), 1);
    assert_eq!(pillars.coords, vec![2, 1]);
    assert_eq!(pillars.point_counts, vec![2]);
    let expected = [
        1.0,
        2.2,
        0.2,
        5.0,
        1.0 - 1.2,
        2.2 - 2.4,
        0.2 - 0.3,
        1.0 - 1.5,
        2.2 - 2.5,
    ];
    for (f, value) in expected.iter().enumerate() {
        assert!(
            (pillars.feature(0, 0, f) - value).abs() < 1e-6,
            "feature {f}: {} vs {value}",
            pillars.feature(0, 0, f)
        );
    }
    // Padding after the pillar's points is zero.
    assert!((0..PILLAR_FEATURES).all(|f| pillars.feature(0, 2, f) == 0.0));
}

#[test]
fn empty_single_and_all_outside() {
    assert!(run(small(), Limits::default(), &[]).is_empty());
    let one = run(small(), Limits::default(), &[[3.5, 0.5, 0.0, 1.0]]);
    assert_eq!(
        (one.coords.clone(), one.point_counts.clone()),
        (vec![0, 3], vec![1])
    );
    // Mean offsets of a single point are zero.
    assert!((4..7).all(|f| one.feature(0, 0, f) == 0.0));
    let outside = run(
        small(),
        Limits::default(),
        &[
            [-0.1, 1.0, 0.0, 0.0],
            [1.0, 4.5, 0.0, 0.0],
            [1.0, 1.0, 1.0, 0.0],
            [1.0, 1.0, -1.5, 0.0],
        ],
    );
    assert!(outside.is_empty());
    assert_eq!(outside.stats.outside_range, 4);
}

#[test]
fn borders_are_half_open() {
    // x = 1.0 is the border between cells 0 and 1: it belongs to cell 1. x = 4.0 (the upper
    // edge) and y = 4.0 are outside; x = 0.0 (the lower edge) is inside cell 0.
    let points = [
        [1.0, 0.5, 0.0, 0.0],
        [0.0, 0.5, 0.0, 0.0],
        [4.0, 0.5, 0.0, 0.0],
        [0.5, 4.0, 0.0, 0.0],
        [3.9999998, 3.9999998, 0.9999999, 0.0],
    ];
    let pillars = run(small(), Limits::default(), &points);
    assert_eq!(pillars.coords, vec![0, 0, 0, 1, 3, 3]);
    assert_eq!(pillars.stats.outside_range, 2);
}

#[test]
fn duplicates_count_separately_and_limits_keep_the_first_points() {
    let points = vec![[2.5, 2.5, 0.0, 1.0]; 10];
    let limited = run(
        small(),
        Limits {
            max_points_per_pillar: 4,
            max_pillars: 10,
        },
        &points,
    );
    assert_eq!(limited.point_counts, vec![4]);
    assert_eq!(limited.stats.dropped_by_pillar_limit, 6);
    // Keeps the first points in input order.
    let ordered: Vec<[f32; 4]> = (0..6).map(|k| [2.5, 2.5, 0.0, k as f32]).collect();
    let kept = run(
        small(),
        Limits {
            max_points_per_pillar: 3,
            max_pillars: 10,
        },
        &ordered,
    );
    assert_eq!(
        (0..3).map(|k| kept.feature(0, k, 3)).collect::<Vec<_>>(),
        vec![0.0, 1.0, 2.0]
    );
}

#[test]
fn max_pillars_keeps_those_nearest_the_ego() {
    // Centred grid: [-2, 2)^2, cells of 1 m. Points in a near cell and two far corners.
    let grid = PillarGrid {
        x_range: [-2.0, 2.0],
        y_range: [-2.0, 2.0],
        z_range: [-1.0, 1.0],
        pillar_size: 1.0,
    };
    let points = [
        [-1.9, -1.9, 0.0, 0.0],
        [0.2, 0.3, 0.0, 0.0],
        [1.9, 1.9, 0.0, 0.0],
        [0.2, 0.4, 0.0, 0.0],
    ];
    let pillars = run(
        grid,
        Limits {
            max_points_per_pillar: 8,
            max_pillars: 1,
        },
        &points,
    );
    assert_eq!(pillars.coords, vec![2, 2]);
    assert_eq!(pillars.point_counts, vec![2]);
    assert_eq!(
        (
            pillars.stats.dropped_pillars,
            pillars.stats.points_in_dropped_pillars
        ),
        (2, 2)
    );
}

#[test]
fn nan_and_inf_are_dropped_and_counted() {
    let points = [
        [f32::NAN, 1.0, 0.0, 0.0],
        [1.0, f32::INFINITY, 0.0, 0.0],
        [1.0, 1.0, 0.0, f32::NEG_INFINITY],
        [1.5, 1.5, 0.0, 2.0],
    ];
    let pillars = run(small(), Limits::default(), &points);
    assert_eq!(pillars.stats.non_finite, 3);
    assert_eq!(pillars.point_counts, vec![1]);
}

/// A deterministic pseudo-random cloud.
fn cloud(n: usize, seed: u64, spread: f32) -> Vec<[f32; 4]> {
    let mut state = seed;
    let mut next = || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    };
    (0..n)
        .map(|_| {
            [
                next() * spread,
                next() * spread,
                next() * 5.0,
                (next() + 1.0) * 50.0,
            ]
        })
        .collect()
}

#[test]
fn sparse_matches_the_dense_reference_on_random_clouds() {
    let grid = PillarGrid::default();
    for (n, limits) in [
        (5_000, Limits::default()),
        (
            20_000,
            Limits {
                max_points_per_pillar: 3,
                max_pillars: 500,
            },
        ),
    ] {
        let pillars = run(grid, limits, &cloud(n, n as u64, 90.0));
        assert!(!pillars.is_empty());
    }
}

#[test]
fn two_million_points_stay_within_the_limits() {
    let grid = PillarGrid::default();
    let limits = Limits {
        max_points_per_pillar: 16,
        max_pillars: 12_000,
    };
    let points = cloud(2_000_000, 7, 85.0);
    let pillars = Pillarizer::new(grid, limits).run(&points);
    assert_eq!(pillars.len(), 12_000);
    assert!(pillars.point_counts.iter().all(|&c| (1..=16).contains(&c)));
    // Output memory is bounded by the limits, whatever the input size.
    assert_eq!(pillars.features.len(), 12_000 * 16 * PILLAR_FEATURES);
    let s = pillars.stats;
    assert_eq!(s.points_in, s.accounted());
}

#[test]
fn the_grid_default_is_the_papers() {
    let grid = PillarGrid::default();
    assert_eq!(grid.size(), (384, 384));
    assert!(grid.validate().is_ok());
    let bad = PillarGrid {
        pillar_size: 0.7,
        ..grid
    };
    assert!(
        bad.validate()
            .unwrap_err()
            .to_string()
            .contains("does not divide")
    );
    let reversed = PillarGrid {
        x_range: [80.0, -80.0],
        ..grid
    };
    assert!(
        reversed
            .validate()
            .unwrap_err()
            .to_string()
            .contains("x_range")
    );
}

#[test]
fn node_parameters_are_validated() {
    let mut registry = bevworld_graph::Registry::new();
    bevworld_pillarize::register(&mut registry);
    let kind = registry.get("pillarize").unwrap();
    let field = |params: serde_json::Value| kind.build(&params).err().and_then(|e| e.field);
    assert!(kind.build(&serde_json::json!({})).is_ok());
    assert_eq!(field(serde_json::json!({"grid": {"x_range": [0, 10], "y_range": [0, 10], "z_range": [-1, 1], "pillar_size": 0.3}})).as_deref(), Some("grid"));
    assert_eq!(
        field(serde_json::json!({"max_points_per_pillar": 0})).as_deref(),
        Some("max_points_per_pillar")
    );
    assert_eq!(
        field(serde_json::json!({"max_pillars": 0})).as_deref(),
        Some("max_pillars")
    );
    assert_eq!(
        field(serde_json::json!({"grid": {"pillar_size": 1.0}})).as_deref(),
        Some("grid"),
        "a partial grid names its missing fields"
    );
}

#[test]
fn bev_statistics_by_hand() {
    // Pillar (iy 2, ix 1) with z 0.2 and 0.4, intensities 5 and 7; one point in (iy 0, ix 3).
    let points = [
        [1.0, 2.2, 0.2, 5.0],
        [1.4, 2.6, 0.4, 7.0],
        [3.5, 0.5, -0.5, 1.0],
    ];
    let pillars = Pillarizer::new(small(), Limits::default()).run(&points);
    let bev = bevworld_pillarize::bev_stats::bev_statistics(&pillars);
    assert_eq!(
        (bev.grid.height, bev.grid.width, bev.channels.len()),
        (4, 4, 5)
    );
    let at = |c: usize, iy: usize, ix: usize| bev.data[c * 16 + iy * 4 + ix];
    assert_eq!(at(0, 2, 1), 1.0);
    assert!((at(1, 2, 1) - 3f32.ln()).abs() < 1e-6);
    assert!(
        (at(2, 2, 1) - 0.4).abs() < 1e-6
            && (at(3, 2, 1) - 0.3).abs() < 1e-6
            && (at(4, 2, 1) - 6.0).abs() < 1e-6
    );
    assert_eq!((at(0, 0, 3), at(2, 0, 3)), (1.0, -0.5));
    // Empty cells are zero in every channel.
    assert!((0..5).all(|c| at(c, 1, 1) == 0.0));
    assert_eq!(bev.data.iter().filter(|v| **v != 0.0).count(), 5 + 5);
}
