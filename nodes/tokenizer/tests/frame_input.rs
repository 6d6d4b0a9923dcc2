//! A real nuScenes frame turned into the tokenizer's inputs and rays: shapes, the agreement of
//! the render rays with the encoder's projection, LiDAR rays that rebuild the sweep, and clear
//! errors for frames and pillars that do not fit the model.

use crate::common;

use common::{nuscenes_frame, tiny};

use std::sync::Arc;

use bevworld_pillarize::{Limits, Pillarizer};
use bevworld_tokenizer::encoder::projection::project_points;
use bevworld_tokenizer::frame_input::{image_planes, planes_to_image};
use bevworld_tokenizer::{FrameInputs, InputError};
use bevworld_types::{PillarGrid, Pillars, PointCloud, SensorFrame};
use burn::prelude::*;
use glam::{DVec3, Vec3};

/// The tiny config's pillar grid: 128 x 128 over [-80, 80) m, heights [-3, 15) m.
fn tiny_grid() -> PillarGrid {
    let grid = FrameInputs::new(&tiny()).pillar_grid();
    assert_eq!(grid.size(), (128, 128));
    grid
}

fn pillarize(frame: &SensorFrame, grid: PillarGrid) -> Pillars {
    let mut points = Vec::new();
    bevworld_pillarize::ego_points_into(&frame.lidar, &mut points);
    Pillarizer::new(grid, Limits::default()).run(&points)
}

#[test]
fn a_real_frame_becomes_encoder_input_of_the_configured_shapes() {
    let device = Device::flex();
    let config = tiny();
    let inputs = FrameInputs::new(&config);
    let Some(frame) = nuscenes_frame() else {
        return;
    };
    let pillars = pillarize(&frame, tiny_grid());
    assert!(pillars.len() > 1000, "{} pillars", pillars.len());
    let input = inputs
        .encoder_input(&frame, &pillars, &device)
        .expect("encoder input");
    let [h, w] = config.image_size;
    let n = config.latent_size();
    let k = config.fusion_heights;
    assert_eq!(input.images.dims(), [6, 3, h, w]);
    assert_eq!(input.pillar_points.dims(), [pillars.len(), 20, 9]);
    assert_eq!(input.pillar_cells.dims(), [pillars.len()]);
    assert_eq!(input.reference.dims(), [6, n * n, k, 2]);

    // Valid point slots are exactly the pillars' point counts.
    let valid: f32 = input.pillar_valid.clone().sum().into_scalar();
    let points: u32 = pillars.point_counts.iter().map(|&c| c.min(20)).sum();
    assert_eq!(valid as u32, points);
    // Every camera sees some reference points; none sees most of a 360° grid.
    let seen = input
        .reference_valid
        .clone()
        .sum_dim(2)
        .sum_dim(1)
        .into_data()
        .try_to_vec::<f32>()
        .expect("counts");
    for (camera, &count) in seen.iter().enumerate() {
        let fraction = count / (n * n * k) as f32;
        assert!(
            fraction > 0.02 && fraction < 0.5,
            "camera {camera} sees {fraction} of the reference points"
        );
    }

    let model = config.init_seeded(0, &device);
    let encoded = model.encode(input);
    let latent = encoded
        .latent
        .into_data()
        .try_to_vec::<f32>()
        .expect("latent");
    assert_eq!(latent.len(), 4 * n * n);
    assert!(latent.iter().all(|v| v.is_finite()));
}

#[test]
fn render_rays_retrace_the_encoder_projection_and_the_lidar_sweep() {
    let config = tiny();
    let inputs = FrameInputs::new(&config);
    let Some(frame) = nuscenes_frame() else {
        return;
    };
    let rays = inputs.frame_rays(&frame).expect("rays");
    let stride = config.render.camera_stride;
    assert_eq!((rays.rows, rays.columns), (64 / stride, 112 / stride));
    let stride = stride as f64;
    assert_eq!(rays.camera.len(), 6 * rays.rows * rays.columns);

    // A point 12 m along each camera ray projects, through the fusion's camera model, onto
    // the centre of that ray's pixel block: rendering and encoding share one geometry.
    for (c, camera) in inputs.fusion_cameras(&frame).iter().enumerate() {
        let first = c * rays.rows * rays.columns;
        let points: Vec<DVec3> = (0..rays.rows * rays.columns)
            .map(|i| {
                let (o, d) = (
                    rays.camera.origins[first + i],
                    rays.camera.directions[first + i],
                );
                DVec3::from(Vec3::from(o)) + 12.0 * DVec3::from(Vec3::from(d))
            })
            .collect();
        let hits = project_points(&points, camera, 0.1);
        for i in 0..rays.rows {
            for j in 0..rays.columns {
                let index = i * rays.columns + j;
                let [u, v] = hits.pixels[index];
                let (eu, ev) = ((j as f64 + 0.5) * stride, (i as f64 + 0.5) * stride);
                assert!(
                    (u - eu).abs() < 5e-3 && (v - ev).abs() < 5e-3,
                    "camera {c} block ({i}, {j}): ({u}, {v}) vs ({eu}, {ev})"
                );
                assert_eq!(hits.valid[index], 1.0);
            }
        }
    }

    // LiDAR rays at the points' ranges rebuild the sweep in the ego frame, all of it but the
    // 8,526 returns off the car itself, and each ray names the point it came from.
    let cloud = &frame.lidar;
    assert_eq!(rays.lidar.len(), cloud.len() - 8_526);
    assert_eq!(rays.lidar_points, cloud.scene_indices());
    let rebuilt =
        bevworld_tokenizer::render::rays::points_from_depths(&rays.lidar, &rays.lidar_ranges);
    for (&index, q) in rays.lidar_points.iter().zip(&rebuilt) {
        let p = &cloud.points[index];
        let ego =
            cloud
                .ego_from_lidar
                .transform_point3(DVec3::new(p.x.into(), p.y.into(), p.z.into()));
        let error = (ego - DVec3::from(Vec3::from(*q))).length();
        assert!(error < 5e-3, "point rebuilt {error} m off");
    }
}

#[test]
fn frames_and_pillars_that_do_not_fit_give_errors_that_say_what_to_change() {
    let device = Device::flex();
    let config = tiny();
    let inputs = FrameInputs::new(&config);
    let Some(frame) = nuscenes_frame() else {
        return;
    };

    // The pillarize node's default grid is the paper's 384 x 384.
    let paper_pillars = pillarize(&frame, PillarGrid::default());
    let error = inputs
        .encoder_input(&frame, &paper_pillars, &device)
        .err()
        .expect("grid mismatch");
    assert!(matches!(error, InputError::PillarGrid { .. }));
    let message = error.to_string();
    assert!(
        message.contains("384 x 384") && message.contains("128 x 128"),
        "{message}"
    );
    assert!(message.contains("`grid`"), "{message}");

    // The same cells over another height range: the pillar features would not be the ones the
    // model learned from.
    let mut low = tiny_grid();
    low.z_range = [-4.5, 4.5];
    let error = inputs
        .encoder_input(&frame, &pillarize(&frame, low), &device)
        .err()
        .expect("height range mismatch");
    let message = error.to_string();
    assert!(
        message.contains("z [-4.5, 4.5]") && message.contains("z [-3.0, 15.0]"),
        "{message}"
    );

    let mut five = frame.clone();
    five.cameras.pop();
    let pillars = pillarize(&frame, tiny_grid());
    let error = inputs
        .encoder_input(&five, &pillars, &device)
        .err()
        .expect("cameras");
    assert!(error.to_string().contains("5 cameras"), "{error}");
    assert!(error.to_string().contains("`cameras`"), "{error}");
    assert!(inputs.frame_rays(&five).is_err());

    let mut broken = pillars.clone();
    broken.coords[1] = 500; // column 500 of a 128-wide grid
    let error = inputs
        .encoder_input(&frame, &broken, &device)
        .err()
        .expect("cell");
    assert!(
        matches!(error, InputError::PillarData { pillar: 0, .. }),
        "{error}"
    );

    let mut truncated = pillars.clone();
    truncated.features.pop();
    assert!(matches!(
        inputs.encoder_input(&frame, &truncated, &device),
        Err(InputError::PillarData { .. })
    ));
}

#[test]
fn an_empty_sweep_still_encodes() {
    let device = Device::flex();
    let config = tiny();
    let inputs = FrameInputs::new(&config);
    let Some(mut frame) = nuscenes_frame() else {
        return;
    };
    frame.lidar = Arc::new(PointCloud {
        points: Vec::new(),
        ..(*frame.lidar).clone()
    });
    let pillars = pillarize(&frame, tiny_grid());
    assert!(pillars.is_empty());
    let input = inputs
        .encoder_input(&frame, &pillars, &device)
        .expect("input");
    assert_eq!(input.pillar_cells.dims(), [1]);
    let valid: f32 = input.pillar_valid.clone().sum().into_scalar();
    assert_eq!(valid, 0.0);
    let latent = config.init_seeded(0, &device).encode(input).latent;
    let values = latent.into_data().try_to_vec::<f32>().expect("latent");
    assert!(values.iter().all(|v| v.is_finite()));
}

#[test]
fn image_planes_scale_to_unit_range_and_round_trip() {
    let image = image::RgbImage::from_fn(3, 2, |x, y| {
        image::Rgb([(x * 100) as u8, (y * 255) as u8, 51])
    });
    let planes = image_planes(&image, 3, 2);
    // Planar [3, H, W]: red row 0 is 0, 100, 200; green row 1 is all 255; blue is 0.2.
    assert_eq!(&planes[0..3], &[0.0, 100.0 / 255.0, 200.0 / 255.0]);
    assert_eq!(&planes[6 + 3..6 + 6], &[1.0, 1.0, 1.0]);
    assert!((planes[12] - 0.2).abs() < 1e-7);
    assert_eq!(planes_to_image(&planes, 3, 2), image);
    // Shrinking a flat image keeps its colour.
    let flat = image::RgbImage::from_pixel(40, 20, image::Rgb([10, 20, 30]));
    let small = image_planes(&flat, 8, 4);
    assert!(small[..32].iter().all(|v| (v - 10.0 / 255.0).abs() < 1e-6));
}
