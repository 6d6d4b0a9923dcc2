//! Rays and the primitives the synthetic world is built from, with exact intersections.
//! World frame: x east, y north, z up, metres.

use glam::{DVec2, DVec3};

#[derive(Clone, Copy, Debug)]
pub struct Ray {
    pub origin: DVec3,
    /// Unit length.
    pub direction: DVec3,
}

impl Ray {
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.direction * t
    }
}

/// Where a ray hit: distance and outward surface normal.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    pub t: f64,
    pub normal: DVec3,
}

/// A shape in the world.
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// A box rotated by `yaw` about z, resting on `z_min`.
    Box {
        center: DVec2,
        half: DVec2,
        yaw: f64,
        z_min: f64,
        z_max: f64,
    },
    /// A rectangle with rounded corners extruded from z_min to z_max (a city block's kerb slab).
    RoundedSlab {
        center: DVec2,
        half: DVec2,
        radius: f64,
        z_min: f64,
        z_max: f64,
    },
    /// A vertical cylinder.
    Cylinder {
        center: DVec2,
        radius: f64,
        z_min: f64,
        z_max: f64,
    },
    Sphere {
        center: DVec3,
        radius: f64,
    },
}

impl Shape {
    /// The 2D bounding box (min, max) in the ground plane.
    pub fn bounds_xy(&self) -> (DVec2, DVec2) {
        match *self {
            Shape::Box {
                center, half, yaw, ..
            } => {
                let (s, c) = yaw.sin_cos();
                let extent = DVec2::new(
                    c.abs() * half.x + s.abs() * half.y,
                    s.abs() * half.x + c.abs() * half.y,
                );
                (center - extent, center + extent)
            }
            Shape::RoundedSlab { center, half, .. } => (center - half, center + half),
            Shape::Cylinder { center, radius, .. } => {
                (center - DVec2::splat(radius), center + DVec2::splat(radius))
            }
            Shape::Sphere { center, radius } => (
                center.truncate() - DVec2::splat(radius),
                center.truncate() + DVec2::splat(radius),
            ),
        }
    }

    pub fn intersect(&self, ray: &Ray, t_max: f64) -> Option<SurfaceHit> {
        match *self {
            Shape::Box {
                center,
                half,
                yaw,
                z_min,
                z_max,
            } => intersect_box(ray, center, half, yaw, z_min, z_max, t_max),
            Shape::RoundedSlab {
                center,
                half,
                radius,
                z_min,
                z_max,
            } => intersect_rounded_slab(ray, center, half, radius, z_min, z_max, t_max),
            Shape::Cylinder {
                center,
                radius,
                z_min,
                z_max,
            } => intersect_cylinder(ray, center, radius, z_min, z_max, t_max),
            Shape::Sphere { center, radius } => intersect_sphere(ray, center, radius, t_max),
        }
    }
}

const EPS: f64 = 1e-9;

/// Slab-method intersection with an oriented box.
fn intersect_box(
    ray: &Ray,
    center: DVec2,
    half: DVec2,
    yaw: f64,
    z_min: f64,
    z_max: f64,
    t_max: f64,
) -> Option<SurfaceHit> {
    let (s, c) = yaw.sin_cos();
    // Into box coordinates.
    let rel = ray.origin.truncate() - center;
    let o = DVec3::new(c * rel.x + s * rel.y, -s * rel.x + c * rel.y, ray.origin.z);
    let d = DVec3::new(
        c * ray.direction.x + s * ray.direction.y,
        -s * ray.direction.x + c * ray.direction.y,
        ray.direction.z,
    );
    let lo = DVec3::new(-half.x, -half.y, z_min);
    let hi = DVec3::new(half.x, half.y, z_max);
    let mut t_enter = f64::NEG_INFINITY;
    let mut t_exit = f64::INFINITY;
    let mut axis = 0usize;
    let mut sign = 0.0;
    for k in 0..3 {
        if d[k].abs() < EPS {
            if o[k] < lo[k] || o[k] > hi[k] {
                return None;
            }
            continue;
        }
        let t1 = (lo[k] - o[k]) / d[k];
        let t2 = (hi[k] - o[k]) / d[k];
        let (near, far, s_near) = if t1 < t2 {
            (t1, t2, -1.0)
        } else {
            (t2, t1, 1.0)
        };
        if near > t_enter {
            t_enter = near;
            axis = k;
            sign = s_near;
        }
        t_exit = t_exit.min(far);
    }
    if t_enter > t_exit || t_enter <= EPS || t_enter >= t_max {
        return None;
    }
    let mut local = DVec3::ZERO;
    local[axis] = sign;
    let normal = DVec3::new(
        c * local.x - s * local.y,
        s * local.x + c * local.y,
        local.z,
    );
    Some(SurfaceHit { t: t_enter, normal })
}

fn intersect_cylinder(
    ray: &Ray,
    center: DVec2,
    radius: f64,
    z_min: f64,
    z_max: f64,
    t_max: f64,
) -> Option<SurfaceHit> {
    let mut best: Option<SurfaceHit> = None;
    // Side.
    let o = ray.origin.truncate() - center;
    let d = ray.direction.truncate();
    let a = d.length_squared();
    if a > EPS {
        let b = o.dot(d);
        let c = o.length_squared() - radius * radius;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let t = (-b - disc.sqrt()) / a;
            let z = ray.origin.z + t * ray.direction.z;
            if t > EPS && t < t_max && z >= z_min && z <= z_max {
                let n = (o + d * t) / radius;
                best = Some(SurfaceHit {
                    t,
                    normal: DVec3::new(n.x, n.y, 0.0),
                });
            }
        }
    }
    // Caps.
    for (z, nz) in [(z_max, 1.0), (z_min, -1.0)] {
        if ray.direction.z.abs() < EPS {
            continue;
        }
        let t = (z - ray.origin.z) / ray.direction.z;
        if t > EPS
            && t < best.map_or(t_max, |h| h.t)
            && (o + d * t).length_squared() <= radius * radius
        {
            best = Some(SurfaceHit {
                t,
                normal: DVec3::new(0.0, 0.0, nz),
            });
        }
    }
    best
}

fn intersect_sphere(ray: &Ray, center: DVec3, radius: f64, t_max: f64) -> Option<SurfaceHit> {
    let o = ray.origin - center;
    let b = o.dot(ray.direction);
    let c = o.length_squared() - radius * radius;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let root = disc.sqrt();
    let t = if -b - root > EPS {
        -b - root
    } else {
        -b + root
    };
    if t <= EPS || t >= t_max {
        return None;
    }
    Some(SurfaceHit {
        t,
        normal: (o + ray.direction * t) / radius,
    })
}

/// Signed distance from a 2D point to a rounded rectangle.
pub fn rounded_rect_sdf(p: DVec2, center: DVec2, half: DVec2, radius: f64) -> f64 {
    let q = (p - center).abs() - (half - DVec2::splat(radius));
    q.max(DVec2::ZERO).length() + q.x.max(q.y).min(0.0) - radius
}

/// A rounded slab: its top face, its four straight sides and its four corner cylinders.
fn intersect_rounded_slab(
    ray: &Ray,
    center: DVec2,
    half: DVec2,
    radius: f64,
    z_min: f64,
    z_max: f64,
    t_max: f64,
) -> Option<SurfaceHit> {
    let mut best: Option<SurfaceHit> = None;
    let mut consider = |hit: Option<SurfaceHit>| {
        if let Some(hit) = hit
            && best.is_none_or(|b| hit.t < b.t)
        {
            best = Some(hit);
        }
    };
    // Top and bottom faces.
    if ray.direction.z.abs() > EPS {
        for (z, nz) in [(z_max, 1.0), (z_min, -1.0)] {
            let t = (z - ray.origin.z) / ray.direction.z;
            if t > EPS
                && t < t_max
                && rounded_rect_sdf(ray.at(t).truncate(), center, half, radius) <= 0.0
            {
                consider(Some(SurfaceHit {
                    t,
                    normal: DVec3::new(0.0, 0.0, nz),
                }));
            }
        }
    }
    // Straight sides: the inner box without the corners, as two boxes.
    let inner_x = DVec2::new(half.x, half.y - radius);
    let inner_y = DVec2::new(half.x - radius, half.y);
    for inner in [inner_x, inner_y] {
        if let Some(hit) = intersect_box(ray, center, inner, 0.0, z_min, z_max, t_max)
            && hit.normal.z == 0.0
        {
            consider(Some(hit));
        }
    }
    // Corner cylinders.
    for (sx, sy) in [(1.0, 1.0), (-1.0, 1.0), (1.0, -1.0), (-1.0, -1.0)] {
        let corner = center + DVec2::new(sx * (half.x - radius), sy * (half.y - radius));
        if let Some(hit) = intersect_cylinder(ray, corner, radius, z_min, z_max, t_max) {
            let p = ray.at(hit.t).truncate() - corner;
            // Only the outward quarter belongs to the slab's surface.
            if hit.normal.z == 0.0 && p.x * sx >= -1e-9 && p.y * sy >= -1e-9 {
                consider(Some(hit));
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ray(origin: [f64; 3], direction: [f64; 3]) -> Ray {
        Ray {
            origin: DVec3::from_array(origin),
            direction: DVec3::from_array(direction).normalize(),
        }
    }

    #[test]
    fn box_hit_distance_and_normal() {
        let shape = Shape::Box {
            center: DVec2::new(10.0, 0.0),
            half: DVec2::new(2.0, 1.0),
            yaw: 0.0,
            z_min: 0.0,
            z_max: 1.5,
        };
        let hit = shape
            .intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0)
            .unwrap();
        assert!((hit.t - 8.0).abs() < 1e-12);
        assert_eq!(hit.normal, DVec3::new(-1.0, 0.0, 0.0));
        // Rotated 90 degrees: the half-extents swap.
        let rotated = Shape::Box {
            center: DVec2::new(10.0, 0.0),
            half: DVec2::new(2.0, 1.0),
            yaw: std::f64::consts::FRAC_PI_2,
            z_min: 0.0,
            z_max: 1.5,
        };
        let hit = rotated
            .intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0)
            .unwrap();
        assert!((hit.t - 9.0).abs() < 1e-9);
        assert!(
            shape
                .intersect(&ray([0.0, 0.0, 2.0], [1.0, 0.0, 0.0]), 100.0)
                .is_none()
        );
    }

    #[test]
    fn cylinder_sphere_and_slab() {
        let pole = Shape::Cylinder {
            center: DVec2::new(5.0, 0.0),
            radius: 0.5,
            z_min: 0.0,
            z_max: 6.0,
        };
        assert!(
            (pole
                .intersect(&ray([0.0, 0.0, 1.0], [1.0, 0.0, 0.0]), 100.0)
                .unwrap()
                .t
                - 4.5)
                .abs()
                < 1e-12
        );
        let ball = Shape::Sphere {
            center: DVec3::new(0.0, 0.0, 10.0),
            radius: 2.0,
        };
        assert!(
            (ball
                .intersect(&ray([0.0, 0.0, 0.0], [0.0, 0.0, 1.0]), 100.0)
                .unwrap()
                .t
                - 8.0)
                .abs()
                < 1e-12
        );
        let slab = Shape::RoundedSlab {
            center: DVec2::ZERO,
            half: DVec2::new(10.0, 10.0),
            radius: 4.0,
            z_min: 0.0,
            z_max: 0.15,
        };
        // Straight side.
        let side = slab
            .intersect(&ray([-20.0, 0.0, 0.1], [1.0, 0.0, 0.0]), 100.0)
            .unwrap();
        assert!((side.t - 10.0).abs() < 1e-9);
        // Diagonal towards the rounded corner: the corner circle, not the sharp box corner.
        let diagonal = slab
            .intersect(&ray([20.0, 20.0, 0.1], [-1.0, -1.0, 0.0]), 100.0)
            .unwrap();
        let expected = (20.0 - 6.0) * 2f64.sqrt() - 4.0;
        assert!(
            (diagonal.t - expected).abs() < 1e-9,
            "{} vs {expected}",
            diagonal.t
        );
        // Top face from above.
        let top = slab
            .intersect(&ray([0.0, 0.0, 5.0], [0.0, 0.0, -1.0]), 100.0)
            .unwrap();
        assert!((top.t - 4.85).abs() < 1e-12 && top.normal.z == 1.0);
    }
}
