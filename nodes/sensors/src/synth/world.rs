//! The synthetic city: a grid road network with two-lane roads, parking strips, kerbed blocks
//! with rounded corners, buildings, poles and trees. Lane markings are painted on the asphalt.
//!
//! Roads run along x at y = j*B and along y at x = i*B (B = block pitch). Traffic keeps right:
//! a lane's centre is half a lane width to the right of the road centre line.

use glam::{DVec2, DVec3};

use super::geometry::Shape;
use super::rng::{Rng, fbm, hash2, value_noise};

/// Road geometry shared by the layout, the traffic and the painter.
#[derive(Clone, Copy, Debug)]
pub struct RoadSpec {
    /// Distance between parallel road centre lines, m.
    pub pitch: f64,
    pub lane_width: f64,
    /// Road centre to kerb, m (two lanes plus a parking strip on each side).
    pub half_width: f64,
    /// Kerb corner rounding radius, m.
    pub corner_radius: f64,
    pub kerb_height: f64,
    /// Intersections along each axis: i and j run over 0..count.
    pub count: i64,
}

impl Default for RoadSpec {
    fn default() -> Self {
        Self {
            pitch: 60.0,
            lane_width: 3.5,
            half_width: 6.0,
            corner_radius: 6.0,
            kerb_height: 0.15,
            count: 9,
        }
    }
}

impl RoadSpec {
    pub fn intersection(&self, i: i64, j: i64) -> DVec2 {
        DVec2::new(i as f64 * self.pitch, j as f64 * self.pitch)
    }

    /// Distance from the nearest road centre line along x and along y.
    fn offsets(&self, p: DVec2) -> (f64, f64) {
        let dy = p.y - (p.y / self.pitch).round() * self.pitch;
        let dx = p.x - (p.x / self.pitch).round() * self.pitch;
        (dx, dy)
    }

    /// Whether `p` is on the drivable surface: inside the town and off every kerbed block
    /// (the blocks are rounded squares between the road centre lines, `City::generate`).
    pub fn is_drivable(&self, p: DVec2) -> bool {
        let (lo, hi) = self.extent();
        if p.x < lo.x || p.y < lo.y || p.x > hi.x || p.y > hi.y {
            return false;
        }
        let block = self.pitch - 2.0 * self.half_width;
        let cell = (p / self.pitch).floor();
        let center = cell * self.pitch + DVec2::splat(self.pitch * 0.5);
        super::geometry::rounded_rect_sdf(p, center, DVec2::splat(block * 0.5), self.corner_radius)
            > 0.0
    }

    pub fn extent(&self) -> (DVec2, DVec2) {
        let margin = self.pitch * 0.5;
        (
            DVec2::splat(-margin),
            DVec2::splat((self.count - 1) as f64 * self.pitch + margin),
        )
    }
}

/// What a surface is made of: drives its colour, texture and LiDAR reflectivity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    Asphalt,
    Kerb,
    Building {
        hue: u8,
    },
    Pole,
    Trunk,
    Foliage,
    Vehicle {
        colour: [u8; 3],
    },
    /// Clothes and skin: matte, a weak LiDAR return.
    Person {
        colour: [u8; 3],
    },
}

/// A shape with its material and, for agents, an instance id.
#[derive(Clone, Copy, Debug)]
pub struct Solid {
    pub shape: Shape,
    pub material: Material,
    /// 0 for static scenery; agents carry their instance number + 1.
    pub instance: u32,
}

/// The static part of the world.
pub struct City {
    pub roads: RoadSpec,
    pub solids: Vec<Solid>,
    /// Parked vehicles: (centre, yaw, size [w, l, h], colour).
    pub parked: Vec<VehicleBody>,
}

#[derive(Clone, Copy, Debug)]
pub struct VehicleBody {
    pub center: DVec2,
    pub yaw: f64,
    /// width, length, height
    pub size: DVec3,
    pub colour: [u8; 3],
}

impl VehicleBody {
    /// A car body and a cabin, as two boxes.
    pub fn solids(&self, instance: u32) -> [Solid; 2] {
        let material = Material::Vehicle {
            colour: self.colour,
        };
        let (s, c) = self.yaw.sin_cos();
        let forward = DVec2::new(c, s);
        let body = Shape::Box {
            center: self.center,
            half: DVec2::new(self.size.y * 0.5, self.size.x * 0.5),
            yaw: self.yaw,
            z_min: 0.25,
            z_max: self.size.z * 0.6,
        };
        let cabin = Shape::Box {
            center: self.center - forward * (self.size.y * 0.08),
            half: DVec2::new(self.size.y * 0.28, self.size.x * 0.45),
            yaw: self.yaw,
            z_min: self.size.z * 0.6,
            z_max: self.size.z,
        };
        [
            Solid {
                shape: body,
                material,
                instance,
            },
            Solid {
                shape: cabin,
                material,
                instance,
            },
        ]
    }
}

pub fn vehicle_colour(rng: &mut Rng) -> [u8; 3] {
    const PALETTE: [[u8; 3]; 8] = [
        [200, 30, 30],
        [30, 60, 170],
        [230, 230, 230],
        [25, 25, 28],
        [120, 124, 130],
        [200, 160, 30],
        [30, 120, 60],
        [160, 170, 185],
    ];
    PALETTE[rng.below(PALETTE.len() as u64) as usize]
}

impl City {
    pub fn generate(seed: u64, roads: RoadSpec) -> Self {
        let mut rng = Rng::fork(seed, 1);
        let mut solids = Vec::new();
        let mut parked = Vec::new();
        let block = roads.pitch - 2.0 * roads.half_width;
        for i in -1..roads.count {
            for j in -1..roads.count {
                let center = roads.intersection(i, j) + DVec2::splat(roads.pitch * 0.5);
                solids.push(Solid {
                    shape: Shape::RoundedSlab {
                        center,
                        half: DVec2::splat(block * 0.5),
                        radius: roads.corner_radius,
                        z_min: -1.0,
                        z_max: roads.kerb_height,
                    },
                    material: Material::Kerb,
                    instance: 0,
                });
                // Buildings set back from the kerb, leaving a 4 m sidewalk.
                let inner = block * 0.5 - 4.0;
                let layout = rng.below(3);
                let footprints: Vec<(DVec2, DVec2)> = match layout {
                    0 => vec![(center, DVec2::splat(inner * rng.range(0.6, 0.95)))],
                    1 => {
                        let h = inner * 0.5;
                        vec![
                            (
                                center + DVec2::new(-h, 0.0),
                                DVec2::new(h * rng.range(0.7, 0.95), inner * rng.range(0.6, 0.95)),
                            ),
                            (
                                center + DVec2::new(h, 0.0),
                                DVec2::new(h * rng.range(0.7, 0.95), inner * rng.range(0.6, 0.95)),
                            ),
                        ]
                    }
                    _ => {
                        let h = inner * 0.5;
                        [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                            .into_iter()
                            .map(|(sx, sy)| {
                                (
                                    center + DVec2::new(sx * h, sy * h),
                                    DVec2::splat(h * rng.range(0.55, 0.9)),
                                )
                            })
                            .collect()
                    }
                };
                for (c, half) in footprints {
                    let height = rng.range(6.0, 30.0);
                    solids.push(Solid {
                        shape: Shape::Box {
                            center: c,
                            half,
                            yaw: 0.0,
                            z_min: roads.kerb_height,
                            z_max: height,
                        },
                        material: Material::Building {
                            hue: rng.below(6) as u8,
                        },
                        instance: 0,
                    });
                }
                // Poles and trees along the sidewalk, 1.5 m in from the kerb.
                let edge = block * 0.5 - 1.5;
                for side in 0..4 {
                    let mut s = -edge + rng.range(2.0, 8.0);
                    while s < edge - 2.0 {
                        let local = match side {
                            0 => DVec2::new(s, -edge),
                            1 => DVec2::new(s, edge),
                            2 => DVec2::new(-edge, s),
                            _ => DVec2::new(edge, s),
                        };
                        let at = center + local;
                        if rng.chance(0.45) {
                            solids.push(Solid {
                                shape: Shape::Cylinder {
                                    center: at,
                                    radius: 0.12,
                                    z_min: 0.0,
                                    z_max: 7.0,
                                },
                                material: Material::Pole,
                                instance: 0,
                            });
                        } else {
                            let trunk = rng.range(2.0, 3.2);
                            let crown = rng.range(1.4, 2.4);
                            solids.push(Solid {
                                shape: Shape::Cylinder {
                                    center: at,
                                    radius: 0.18,
                                    z_min: 0.0,
                                    z_max: trunk + crown * 0.5,
                                },
                                material: Material::Trunk,
                                instance: 0,
                            });
                            solids.push(Solid {
                                shape: Shape::Sphere {
                                    center: at.extend(trunk + crown),
                                    radius: crown,
                                },
                                material: Material::Foliage,
                                instance: 0,
                            });
                        }
                        s += rng.range(9.0, 16.0);
                    }
                }
            }
        }
        // Parked cars in the parking strips, away from intersections.
        let strip = roads.lane_width + (roads.half_width - roads.lane_width) * 0.5;
        for i in 0..roads.count {
            for j in 0..roads.count {
                for (axis_x, side) in [(true, 1.0), (true, -1.0), (false, 1.0), (false, -1.0)] {
                    if i == roads.count - 1 && axis_x || j == roads.count - 1 && !axis_x {
                        continue;
                    }
                    let start = roads.intersection(i, j);
                    let mut s = roads.half_width + roads.corner_radius + 3.0 + rng.range(0.0, 6.0);
                    while s < roads.pitch - roads.half_width - roads.corner_radius - 3.0 {
                        if rng.chance(0.35) {
                            let (center, yaw) = if axis_x {
                                (
                                    start + DVec2::new(s, side * strip),
                                    if side > 0.0 {
                                        std::f64::consts::PI
                                    } else {
                                        0.0
                                    },
                                )
                            } else {
                                (
                                    start + DVec2::new(-side * strip, s),
                                    if side > 0.0 {
                                        std::f64::consts::FRAC_PI_2
                                    } else {
                                        -std::f64::consts::FRAC_PI_2
                                    },
                                )
                            };
                            parked.push(VehicleBody {
                                center,
                                yaw,
                                size: DVec3::new(
                                    rng.range(1.75, 1.95),
                                    rng.range(4.2, 4.8),
                                    rng.range(1.45, 1.7),
                                ),
                                colour: vehicle_colour(&mut rng),
                            });
                        }
                        s += rng.range(5.5, 7.5);
                    }
                }
            }
        }
        Self {
            roads,
            solids,
            parked,
        }
    }
}

/// The ground's (z = 0) albedo at a point: asphalt with painted lane markings.
pub fn asphalt_albedo(roads: &RoadSpec, p: DVec2) -> ([f64; 3], f64) {
    let grain = 0.75 + 0.5 * fbm(p.x * 1.7, p.y * 1.7, 11);
    let stain = 0.85 + 0.3 * value_noise(p.x * 0.08, p.y * 0.08, 12);
    let base = 0.16 * grain * stain;
    let mut colour = [base, base, base * 1.04];
    let mut reflectivity = 0.12;
    let (dx, dy) = offsets_of(roads, p);
    let in_intersection = dx.abs() < roads.half_width && dy.abs() < roads.half_width;
    // Markings on the road along x (|dy| small) and along y (|dx| small), not inside junctions.
    for (across, along) in [(dy, p.x), (dx, p.y)] {
        if in_intersection || across.abs() > roads.half_width {
            continue;
        }
        let dash = along.rem_euclid(6.0) < 3.0;
        let centre_line = across.abs() < 0.08;
        let lane_edge = (across.abs() - roads.lane_width).abs() < 0.07;
        if centre_line && dash {
            colour = [0.85, 0.72, 0.2];
            reflectivity = 0.75;
        } else if lane_edge {
            colour = [0.85, 0.85, 0.82];
            reflectivity = 0.8;
        }
    }
    // Stop lines before each junction.
    let stop_line = |across: f64, along_from_center: f64| {
        across.abs() < roads.lane_width
            && (along_from_center.abs() - (roads.half_width + 1.0)).abs() < 0.2
    };
    if (stop_line(dy, dx) && dx * dy < 0.0) || (stop_line(dx, dy) && dx * dy > 0.0) {
        colour = [0.88, 0.88, 0.86];
        reflectivity = 0.8;
    }
    (colour, reflectivity)
}

fn offsets_of(roads: &RoadSpec, p: DVec2) -> (f64, f64) {
    roads.offsets(p)
}

/// Albedo and LiDAR reflectivity of a solid's surface at a world point.
pub fn solid_albedo(material: Material, p: DVec3, normal: DVec3) -> ([f64; 3], f64) {
    match material {
        Material::Asphalt => ([0.16, 0.16, 0.17], 0.12),
        Material::Kerb => {
            let tile =
                ((p.x / 1.2).floor() as i64 + (p.y / 1.2).floor() as i64).rem_euclid(2) as f64;
            let grain = 0.9 + 0.2 * value_noise(p.x * 3.0, p.y * 3.0, 21);
            let v = (0.5 + 0.05 * tile) * grain;
            if normal.z.abs() < 0.5 {
                ([0.62, 0.62, 0.6], 0.35)
            } else {
                ([v, v * 0.98, v * 0.93], 0.3)
            }
        }
        Material::Building { hue } => {
            const WALLS: [[f64; 3]; 6] = [
                [0.72, 0.66, 0.58],
                [0.55, 0.38, 0.3],
                [0.62, 0.64, 0.68],
                [0.8, 0.78, 0.7],
                [0.45, 0.47, 0.5],
                [0.7, 0.55, 0.42],
            ];
            let wall = WALLS[hue as usize % WALLS.len()];
            if normal.z.abs() > 0.5 {
                return ([0.35, 0.34, 0.33], 0.2);
            }
            // Windows: a 3 m x 3.2 m grid of dark glass on every facade.
            let along = if normal.x.abs() > normal.y.abs() {
                p.y
            } else {
                p.x
            };
            let u = along.rem_euclid(3.0);
            let v = (p.z - 0.15).rem_euclid(3.2);
            let window = (0.6..2.4).contains(&u) && (0.9..2.5).contains(&v) && p.z > 1.0;
            if window {
                let tint = 0.15
                    + 0.1 * hash2((along / 3.0).floor() as i64, (p.z / 3.2).floor() as i64, 31);
                ([tint, tint * 1.1, tint * 1.3], 0.1)
            } else {
                let grain = 0.92 + 0.16 * value_noise(along * 2.0, p.z * 2.0, 32);
                ([wall[0] * grain, wall[1] * grain, wall[2] * grain], 0.45)
            }
        }
        Material::Pole => ([0.38, 0.4, 0.42], 0.5),
        Material::Trunk => ([0.3, 0.22, 0.15], 0.3),
        Material::Foliage => {
            let n = value_noise(p.x * 4.0 + p.z * 3.0, p.y * 4.0 - p.z * 2.0, 41);
            ([0.12 + 0.1 * n, 0.3 + 0.2 * n, 0.1 + 0.06 * n], 0.25)
        }
        Material::Person { colour } => (
            [
                f64::from(colour[0]) / 255.0,
                f64::from(colour[1]) / 255.0,
                f64::from(colour[2]) / 255.0,
            ],
            0.3,
        ),
        Material::Vehicle { colour } => {
            let c = [
                f64::from(colour[0]) / 255.0,
                f64::from(colour[1]) / 255.0,
                f64::from(colour[2]) / 255.0,
            ];
            // Darker glass on the cabin's sides.
            if normal.z.abs() < 0.5 && p.z > 1.05 {
                ([c[0] * 0.25, c[1] * 0.25, c[2] * 0.3], 0.15)
            } else {
                (c, 0.6)
            }
        }
    }
}
