//! Ray casting the synthetic world: a snapshot of every solid at one instant, a uniform BEV grid
//! traversed cell by cell (Amanatides-Woo), and the two sensors built on it.

use glam::{DVec2, DVec3};
use image::RgbImage;
use rayon::prelude::*;

use bevworld_types::{Intrinsics, LidarPoint, Pose};

use super::geometry::Ray;
use super::rng::Rng;
use super::world::{Material, RoadSpec, Solid, asphalt_albedo, solid_albedo};

/// What a ray hit.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    pub t: f64,
    pub point: DVec3,
    pub normal: DVec3,
    pub material: Material,
    /// 0 for scenery, agent instance + 1 otherwise.
    pub instance: u32,
}

/// Every solid at one instant, indexed by a BEV grid.
pub struct Snapshot {
    pub roads: RoadSpec,
    solids: Vec<Solid>,
    origin: DVec2,
    cell: f64,
    size: (usize, usize),
    cells: Vec<Vec<u32>>,
}

const CELL: f64 = 6.0;

impl Snapshot {
    pub fn new(roads: RoadSpec, solids: Vec<Solid>) -> Self {
        let (mut lo, mut hi) = roads.extent();
        for solid in &solids {
            let (a, b) = solid.shape.bounds_xy();
            lo = lo.min(a);
            hi = hi.max(b);
        }
        lo -= DVec2::splat(CELL);
        hi += DVec2::splat(CELL);
        let size = (
            ((hi.x - lo.x) / CELL).ceil() as usize,
            ((hi.y - lo.y) / CELL).ceil() as usize,
        );
        let mut cells = vec![Vec::new(); size.0 * size.1];
        for (index, solid) in solids.iter().enumerate() {
            let (a, b) = solid.shape.bounds_xy();
            let (x0, y0) = (
                ((a.x - lo.x) / CELL).floor() as usize,
                ((a.y - lo.y) / CELL).floor() as usize,
            );
            let (x1, y1) = (
                ((b.x - lo.x) / CELL).floor() as usize,
                ((b.y - lo.y) / CELL).floor() as usize,
            );
            for y in y0..=y1.min(size.1 - 1) {
                for x in x0..=x1.min(size.0 - 1) {
                    cells[y * size.0 + x].push(index as u32);
                }
            }
        }
        Self {
            roads,
            solids,
            origin: lo,
            cell: CELL,
            size,
            cells,
        }
    }

    /// The closest hit along a ray within `t_max`, or None for open sky.
    pub fn cast(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        // The ground plane (asphalt) bounds the search for rays going down.
        let t_ground = ground_distance(ray);
        let mut best: Option<(f64, DVec3, usize)> = None;
        let limit = t_max.min(t_ground);

        // Grid traversal in x, y.
        let local = ray.origin.truncate() - self.origin;
        let d = ray.direction.truncate();
        let mut cx = (local.x / self.cell).floor() as i64;
        let mut cy = (local.y / self.cell).floor() as i64;
        let step_x: i64 = if d.x >= 0.0 { 1 } else { -1 };
        let step_y: i64 = if d.y >= 0.0 { 1 } else { -1 };
        let next_boundary = |c: i64, step: i64| (c + i64::from(step > 0)) as f64 * self.cell;
        let mut t_max_x = if d.x.abs() > 1e-12 {
            (next_boundary(cx, step_x) - local.x) / d.x
        } else {
            f64::INFINITY
        };
        let mut t_max_y = if d.y.abs() > 1e-12 {
            (next_boundary(cy, step_y) - local.y) / d.y
        } else {
            f64::INFINITY
        };
        let t_delta_x = if d.x.abs() > 1e-12 {
            self.cell / d.x.abs()
        } else {
            f64::INFINITY
        };
        let t_delta_y = if d.y.abs() > 1e-12 {
            self.cell / d.y.abs()
        } else {
            f64::INFINITY
        };
        let mut t_cell_start = 0.0;
        loop {
            if cx < 0
                || cy < 0
                || cx >= self.size.0 as i64
                || cy >= self.size.1 as i64
                || t_cell_start > limit
            {
                break;
            }
            let t_cell_end = t_max_x.min(t_max_y);
            let bound = best.map_or(limit, |b| b.0);
            for &index in &self.cells[cy as usize * self.size.0 + cx as usize] {
                if let Some(hit) = self.solids[index as usize]
                    .shape
                    .intersect(ray, bound.min(best.map_or(f64::INFINITY, |b| b.0)))
                    && best.is_none_or(|b| hit.t < b.0)
                {
                    best = Some((hit.t, hit.normal, index as usize));
                }
            }
            if best.is_some_and(|b| b.0 <= t_cell_end) {
                break;
            }
            t_cell_start = t_cell_end;
            if t_max_x < t_max_y {
                cx += step_x;
                t_max_x += t_delta_x;
            } else {
                cy += step_y;
                t_max_y += t_delta_y;
            }
        }
        match best {
            Some((t, normal, index)) if t <= limit => {
                let solid = &self.solids[index];
                Some(Hit {
                    t,
                    point: ray.at(t),
                    normal,
                    material: solid.material,
                    instance: solid.instance,
                })
            }
            _ => ground_hit(ray, t_ground, t_max),
        }
    }

    /// The same query by testing every solid: the reference the grid is checked against.
    pub fn cast_brute_force(&self, ray: &Ray, t_max: f64) -> Option<Hit> {
        let t_ground = ground_distance(ray);
        let mut best: Option<Hit> = None;
        for solid in &self.solids {
            if let Some(hit) = solid.shape.intersect(ray, best.map_or(t_max, |b| b.t)) {
                best = Some(Hit {
                    t: hit.t,
                    point: ray.at(hit.t),
                    normal: hit.normal,
                    material: solid.material,
                    instance: solid.instance,
                });
            }
        }
        match best {
            Some(hit) if hit.t <= t_ground => Some(hit),
            _ => ground_hit(ray, t_ground, t_max),
        }
    }

    /// Albedo and LiDAR reflectivity at a hit.
    pub fn albedo(&self, hit: &Hit) -> ([f64; 3], f64) {
        match hit.material {
            Material::Asphalt => asphalt_albedo(&self.roads, hit.point.truncate()),
            material => solid_albedo(material, hit.point, hit.normal),
        }
    }

    pub fn solids(&self) -> &[Solid] {
        &self.solids
    }
}

/// Distance along a ray to the ground plane z = 0 (infinite for rays that do not go down).
fn ground_distance(ray: &Ray) -> f64 {
    if ray.direction.z < -1e-12 {
        -ray.origin.z / ray.direction.z
    } else {
        f64::INFINITY
    }
}

/// The asphalt hit at `t_ground`, if it is within range.
fn ground_hit(ray: &Ray, t_ground: f64, t_max: f64) -> Option<Hit> {
    (t_ground <= t_max).then(|| Hit {
        t: t_ground,
        point: ray.at(t_ground),
        normal: DVec3::Z,
        material: Material::Asphalt,
        instance: 0,
    })
}

const SUN: DVec3 = DVec3::new(0.45, 0.3, 0.84);

fn sky(direction: DVec3) -> [f64; 3] {
    let up = direction.z.clamp(0.0, 1.0);
    [0.62 - 0.25 * up, 0.72 - 0.2 * up, 0.86 - 0.05 * up]
}

/// Renders one camera: `global_from_camera` maps the camera frame (x right, y down, z forward)
/// to the world. Returns the image and, per pixel, the instance id that was hit.
pub fn render_camera(
    snapshot: &Snapshot,
    intrinsics: &Intrinsics,
    global_from_camera: &Pose,
    far: f64,
) -> (RgbImage, Vec<u32>) {
    let (width, height) = (intrinsics.width as usize, intrinsics.height as usize);
    let origin = global_from_camera.translation;
    let sun = SUN.normalize();
    let rows: Vec<(Vec<u8>, Vec<u32>)> = (0..height)
        .into_par_iter()
        .map(|v| {
            let mut pixels = Vec::with_capacity(width * 3);
            let mut ids = Vec::with_capacity(width);
            for u in 0..width {
                let camera_dir = DVec3::new(
                    (u as f64 + 0.5 - intrinsics.cx) / intrinsics.fx,
                    (v as f64 + 0.5 - intrinsics.cy) / intrinsics.fy,
                    1.0,
                );
                let direction = global_from_camera.transform_vector3(camera_dir).normalize();
                let ray = Ray { origin, direction };
                let (colour, id) = match snapshot.cast(&ray, far) {
                    Some(hit) => {
                        let (albedo, _) = snapshot.albedo(&hit);
                        let light = 0.38 + 0.62 * hit.normal.dot(sun).max(0.0);
                        let fog = 1.0 - (-hit.t / 450.0).exp();
                        let haze = sky(direction);
                        let shade = |k: usize| albedo[k] * light * (1.0 - fog) + haze[k] * fog;
                        ([shade(0), shade(1), shade(2)], hit.instance)
                    }
                    None => (sky(direction), 0),
                };
                for c in colour {
                    // Display gamma, then 8 bits.
                    pixels.push((c.clamp(0.0, 1.0).powf(1.0 / 2.2) * 255.0).round() as u8);
                }
                ids.push(id);
            }
            (pixels, ids)
        })
        .collect();
    let mut buffer = Vec::with_capacity(width * height * 3);
    let mut instances = Vec::with_capacity(width * height);
    for (pixels, ids) in rows {
        buffer.extend_from_slice(&pixels);
        instances.extend_from_slice(&ids);
    }
    let image = RgbImage::from_raw(intrinsics.width, intrinsics.height, buffer)
        .unwrap_or_else(|| RgbImage::new(1, 1));
    (image, instances)
}

/// A spinning multi-beam LiDAR.
#[derive(Clone, Debug)]
pub struct LidarSpec {
    /// Beam elevations, degrees, lowest first (ring 0).
    pub elevations_deg: Vec<f64>,
    pub azimuth_step_deg: f64,
    pub min_range: f64,
    pub max_range: f64,
    /// Standard deviation of range noise, m (0 = exact).
    pub range_noise: f64,
    /// Probability that a return is lost.
    pub drop_probability: f64,
}

impl LidarSpec {
    /// 32 beams from -30 to +10 degrees, like nuScenes' HDL-32E.
    pub fn nuscenes_like(azimuth_step_deg: f64) -> Self {
        Self {
            elevations_deg: (0..32).map(|k| -30.0 + 40.0 * k as f64 / 31.0).collect(),
            azimuth_step_deg,
            min_range: 1.0,
            max_range: 100.0,
            range_noise: 0.0,
            drop_probability: 0.0,
        }
    }

    /// The unit direction of beam `ring` at azimuth column `column`, in the LiDAR frame.
    pub fn direction(&self, ring: usize, column: usize) -> DVec3 {
        let elevation = self.elevations_deg[ring].to_radians();
        let azimuth = (column as f64 * self.azimuth_step_deg).to_radians();
        DVec3::new(
            elevation.cos() * azimuth.cos(),
            elevation.cos() * azimuth.sin(),
            elevation.sin(),
        )
    }

    pub fn columns(&self) -> usize {
        (360.0 / self.azimuth_step_deg).round() as usize
    }
}

/// One sweep, instantaneous at the snapshot's time. Points are in the LiDAR frame; the second
/// vector holds each point's instance id.
pub fn scan_lidar(
    snapshot: &Snapshot,
    spec: &LidarSpec,
    global_from_lidar: &Pose,
    noise_seed: u64,
) -> (Vec<LidarPoint>, Vec<u32>) {
    let origin = global_from_lidar.translation;
    let columns = spec.columns();
    let per_ring: Vec<(Vec<LidarPoint>, Vec<u32>)> = (0..spec.elevations_deg.len())
        .into_par_iter()
        .map(|ring| {
            let mut rng = Rng::fork(noise_seed, ring as u64);
            let mut points = Vec::new();
            let mut ids = Vec::new();
            for column in 0..columns {
                let local = spec.direction(ring, column);
                let ray = Ray {
                    origin,
                    direction: global_from_lidar.transform_vector3(local),
                };
                let Some(hit) = snapshot.cast(&ray, spec.max_range) else {
                    continue;
                };
                // Draw noise for every return so the stream does not depend on what was hit.
                let noise = rng.normal() * spec.range_noise;
                let dropped = rng.chance(spec.drop_probability);
                let range = hit.t + noise;
                if dropped || range < spec.min_range || range > spec.max_range {
                    continue;
                }
                let (_, reflectivity) = snapshot.albedo(&hit);
                let incidence = hit.normal.dot(-ray.direction).abs();
                let intensity = (reflectivity * (0.3 + 0.7 * incidence) * 255.0)
                    .round()
                    .clamp(0.0, 255.0);
                let p = local * range;
                points.push(LidarPoint {
                    x: p.x as f32,
                    y: p.y as f32,
                    z: p.z as f32,
                    intensity: intensity as f32,
                    ring: ring as u16,
                });
                ids.push(hit.instance);
            }
            (points, ids)
        })
        .collect();
    let mut points = Vec::new();
    let mut ids = Vec::new();
    for (p, i) in per_ring {
        points.extend(p);
        ids.extend(i);
    }
    (points, ids)
}
