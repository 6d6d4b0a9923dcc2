//! Pedestrians on the sidewalks and cyclists at the edge of the lanes: the road users a
//! detector must find besides cars, with their own sizes, speeds and behaviour.
//!
//! - **Pedestrians** walk along a block's sidewalk, between the kerb and the buildings, at
//!   0.8–1.6 m/s, turning back at the block's ends; about a third stand still. Their box is
//!   about 0.6 × 0.6 × 1.75 m (`human.pedestrian.adult`, `pedestrian.moving` or
//!   `pedestrian.standing`).
//! - **Cyclists** ride along a road at 3–6 m/s, on the right-hand edge of the lane, turning back
//!   after three blocks. Their box, bicycle and rider, is about 0.6 × 1.8 × 1.7 m
//!   (`vehicle.bicycle`, `cycle.with_rider`).
//!
//! Each is drawn from its own random stream (`Rng::fork(seed, 4)` and `(seed, 5)`), so a scene
//! without them is byte for byte the scene it was before they existed.

use glam::{DVec2, DVec3};

use super::geometry::Shape;
use super::rng::Rng;
use super::world::{Material, RoadSpec, Solid, VehicleBody};

/// What a person is, for its shape and its annotation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PersonKind {
    Pedestrian,
    Cyclist,
}

/// A person moving back and forth along a straight stretch.
#[derive(Clone, Debug)]
pub struct Person {
    pub kind: PersonKind,
    /// Width, length, height of its annotated box.
    pub size: DVec3,
    pub colour: [u8; 3],
    /// The stretch: from `start` along `direction` for `length` metres.
    start: DVec2,
    direction: DVec2,
    length: f64,
    /// Where along the stretch it is at t = 0, m.
    offset: f64,
    /// m/s; 0 for a pedestrian standing.
    pub speed: f64,
}

impl Person {
    /// Its body at `t` seconds from the scene start: the position along the stretch, walking
    /// or riding to its end and back.
    pub fn body_at(&self, t: f64) -> VehicleBody {
        let travelled = self.offset + self.speed * t.max(0.0);
        let period = 2.0 * self.length;
        let phase = travelled.rem_euclid(period);
        let (along, heading) = if phase <= self.length {
            (phase, self.direction)
        } else {
            (period - phase, -self.direction)
        };
        VehicleBody {
            center: self.start + self.direction * along,
            yaw: heading.y.atan2(heading.x),
            size: self.size,
            colour: self.colour,
        }
    }

    pub fn is_moving(&self) -> bool {
        self.speed > 0.0
    }

    /// The nuScenes category of its annotation.
    pub fn category(&self) -> &'static str {
        match self.kind {
            PersonKind::Pedestrian => "human.pedestrian.adult",
            PersonKind::Cyclist => "vehicle.bicycle",
        }
    }

    /// The nuScenes attribute of its annotation.
    pub fn attribute(&self) -> &'static str {
        match (self.kind, self.is_moving()) {
            (PersonKind::Pedestrian, true) => "pedestrian.moving",
            (PersonKind::Pedestrian, false) => "pedestrian.standing",
            (PersonKind::Cyclist, _) => "cycle.with_rider",
        }
    }
}

/// The boxes a person is drawn with: legs, torso and head for a pedestrian; the bicycle's frame
/// and wheels, and the rider's body, for a cyclist.
pub fn person_solids(kind: PersonKind, body: &VehicleBody, instance: u32) -> Vec<Solid> {
    let (s, c) = body.yaw.sin_cos();
    let forward = DVec2::new(c, s);
    let part = |along: f64, half_length: f64, half_width: f64, z: (f64, f64), material| Solid {
        shape: Shape::Box {
            center: body.center + forward * along,
            half: DVec2::new(half_length, half_width),
            yaw: body.yaw,
            z_min: z.0,
            z_max: z.1,
        },
        material,
        instance,
    };
    let clothes = Material::Person {
        colour: body.colour,
    };
    let skin = Material::Person {
        colour: [205, 160, 130],
    };
    let h = body.size.z;
    match kind {
        PersonKind::Pedestrian => vec![
            part(
                0.0,
                0.12,
                0.16,
                (0.0, 0.48 * h),
                Material::Person {
                    colour: [45, 45, 60],
                },
            ),
            part(0.0, 0.14, 0.24, (0.48 * h, 0.86 * h), clothes),
            part(0.0, 0.1, 0.1, (0.87 * h, h), skin),
        ],
        PersonKind::Cyclist => {
            let frame = Material::Vehicle {
                colour: [60, 60, 64],
            };
            let l = body.size.y;
            vec![
                // Two wheels and the frame between them.
                part(0.33 * l, 0.2, 0.03, (0.0, 0.68), frame),
                part(-0.33 * l, 0.2, 0.03, (0.0, 0.68), frame),
                part(0.0, 0.3 * l, 0.04, (0.4, 0.95), frame),
                // The rider: legs, torso, head.
                part(
                    -0.05 * l,
                    0.12,
                    0.18,
                    (0.6, 1.0),
                    Material::Person {
                        colour: [45, 45, 60],
                    },
                ),
                part(0.02 * l, 0.16, 0.2, (1.0, 0.86 * h), clothes),
                part(0.05 * l, 0.1, 0.1, (0.87 * h, h), skin),
            ]
        }
    }
}

const CLOTHES: [[u8; 3]; 6] = [
    [180, 40, 40],
    [40, 70, 160],
    [230, 190, 40],
    [30, 30, 30],
    [90, 140, 80],
    [200, 200, 205],
];

/// Pedestrians on the sidewalks of the blocks around intersection `around`.
pub fn spawn_pedestrians(
    rng: &mut Rng,
    roads: &RoadSpec,
    around: (i64, i64),
    count: usize,
) -> Vec<Person> {
    (0..count)
        .map(|_| {
            let (along_x, start, side) = stretch(rng, roads, around);
            // The sidewalk: between the kerb and the buildings, 4 m back from it.
            let lateral = roads.half_width + rng.range(1.0, 3.0);
            let direction = if along_x { DVec2::X } else { DVec2::Y };
            let normal = DVec2::new(-direction.y, direction.x) * side;
            let length = roads.pitch - 2.0 * roads.half_width - 2.0;
            let walking = rng.below(3) != 0;
            Person {
                kind: PersonKind::Pedestrian,
                size: DVec3::new(
                    rng.range(0.55, 0.7),
                    rng.range(0.55, 0.75),
                    rng.range(1.6, 1.9),
                ),
                colour: CLOTHES[rng.below(CLOTHES.len() as u64) as usize],
                start: start + direction * (roads.half_width + 1.0) + normal * lateral,
                direction,
                length,
                offset: rng.range(0.0, 2.0 * length),
                speed: if walking { rng.range(0.8, 1.6) } else { 0.0 },
            }
        })
        .collect()
}

/// Cyclists riding the roads around intersection `around`.
pub fn spawn_cyclists(
    rng: &mut Rng,
    roads: &RoadSpec,
    around: (i64, i64),
    count: usize,
) -> Vec<Person> {
    (0..count)
        .map(|_| {
            let (along_x, start, side) = stretch(rng, roads, around);
            let direction = if along_x { DVec2::X } else { DVec2::Y };
            // Right-hand traffic: on the right of its heading, at the lane's outer edge.
            let heading = direction * side;
            let right = DVec2::new(heading.y, -heading.x);
            let length = 3.0 * roads.pitch;
            Person {
                kind: PersonKind::Cyclist,
                size: DVec3::new(
                    rng.range(0.55, 0.7),
                    rng.range(1.7, 1.9),
                    rng.range(1.6, 1.8),
                ),
                colour: CLOTHES[rng.below(CLOTHES.len() as u64) as usize],
                start: start - heading * roads.pitch + right * (roads.lane_width * 0.8),
                direction: heading,
                length,
                offset: rng.range(0.0, 2.0 * length),
                speed: rng.range(3.0, 6.0),
            }
        })
        .collect()
}

/// A road or block side near `around`: along x or y, from which intersection, and on which side.
fn stretch(rng: &mut Rng, roads: &RoadSpec, around: (i64, i64)) -> (bool, DVec2, f64) {
    let i = (around.0 + rng.below(3) as i64 - 1).clamp(0, roads.count - 2);
    let j = (around.1 + rng.below(3) as i64 - 1).clamp(0, roads.count - 2);
    let along_x = rng.below(2) == 0;
    let side = if rng.below(2) == 0 { 1.0 } else { -1.0 };
    (along_x, roads.intersection(i, j), side)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_person_walks_to_the_end_of_its_stretch_and_back() {
        let person = Person {
            kind: PersonKind::Pedestrian,
            size: DVec3::new(0.6, 0.6, 1.75),
            colour: [0, 0, 0],
            start: DVec2::ZERO,
            direction: DVec2::X,
            length: 10.0,
            offset: 0.0,
            speed: 1.0,
        };
        let at = |t: f64| person.body_at(t);
        assert!((at(4.0).center - DVec2::new(4.0, 0.0)).length() < 1e-12);
        assert!(at(4.0).yaw.abs() < 1e-12);
        // Past the end, it comes back facing the other way.
        assert!((at(13.0).center - DVec2::new(7.0, 0.0)).length() < 1e-12);
        assert!((at(13.0).yaw.abs() - std::f64::consts::PI).abs() < 1e-12);
        assert!((at(20.0).center - DVec2::ZERO).length() < 1e-12);
        let standing = Person {
            speed: 0.0,
            ..person.clone()
        };
        assert_eq!(standing.attribute(), "pedestrian.standing");
        assert_eq!(person.attribute(), "pedestrian.moving");
        assert_eq!(person.category(), "human.pedestrian.adult");
    }

    #[test]
    fn people_stay_off_the_lanes_or_on_them_as_their_kind_does() {
        let roads = RoadSpec::default();
        let mut rng = Rng::fork(3, 4);
        for person in spawn_pedestrians(&mut rng, &roads, (2, 2), 50) {
            for t in [0.0, 7.0, 31.0] {
                let c = person.body_at(t).center;
                // Distance to the nearest road centre line, across the stretch's direction.
                let across = if person.direction.x.abs() > 0.5 {
                    c.y
                } else {
                    c.x
                };
                let off =
                    (across / roads.pitch - (across / roads.pitch).round()).abs() * roads.pitch;
                assert!(
                    off > roads.half_width && off < roads.half_width + 4.0,
                    "a pedestrian {off} m from the road centre"
                );
            }
        }
        let mut rng = Rng::fork(3, 5);
        for person in spawn_cyclists(&mut rng, &roads, (2, 2), 50) {
            let c = person.body_at(5.0).center;
            let across = if person.direction.x.abs() > 0.5 {
                c.y
            } else {
                c.x
            };
            let off = (across / roads.pitch - (across / roads.pitch).round()).abs() * roads.pitch;
            assert!(
                off > 1.0 && off < roads.half_width - 2.0,
                "a cyclist {off} m from the centre"
            );
        }
    }
}
