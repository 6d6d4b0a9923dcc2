//! Annotated objects: the 3D boxes a dataset gives its road users at each keyframe, with their
//! class and motion. The forecast metrics split a sweep by them (points on moving vehicles, on
//! parked ones, the static rest), since a world model is judged by its agents.

use glam::DVec3;

use crate::pose::Pose;

/// An object at one keyframe, as the dataset annotates it (nuScenes `sample_annotation`).
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectBox {
    /// The object across keyframes (nuScenes `instance_token`).
    pub instance_token: String,
    /// The category's name, e.g. `vehicle.car`, `human.pedestrian.adult`.
    pub category: String,
    /// Its centre and heading: x forward along the box's length.
    pub global_from_box: Pose,
    /// Width, length, height in metres (the nuScenes order).
    pub size: [f64; 3],
    /// Planar velocity in the global frame, m/s, from its previous and next annotations (as
    /// the nuScenes devkit's `box_velocity`); `None` for an object annotated once.
    pub velocity: Option<[f64; 2]>,
    /// Its attributes' names (`vehicle.moving`, `pedestrian.standing`, …); nuScenes gives at
    /// most one.
    pub attributes: Vec<String>,
    /// LiDAR and radar returns inside it, as the dataset counts them: a box with none is not
    /// scored by the detection metrics.
    pub num_pts: i64,
}

/// How fast an object must go to count as moving, m/s: below it, annotation noise.
pub const MOVING_SPEED_MPS: f64 = 0.5;

/// Where a point lies with respect to the road users.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PointClass {
    /// On a vehicle that moves (`MOVING_SPEED_MPS`).
    MovingVehicle,
    /// On a vehicle that stands.
    ParkedVehicle,
    /// Everything else: the road, buildings, poles, and objects that are not vehicles.
    Static,
}

impl PointClass {
    pub const ALL: [PointClass; 3] = [
        PointClass::MovingVehicle,
        PointClass::ParkedVehicle,
        PointClass::Static,
    ];

    /// The name the metrics use: `moving_vehicles`, `parked_vehicles`, `static`.
    pub fn name(self) -> &'static str {
        match self {
            PointClass::MovingVehicle => "moving_vehicles",
            PointClass::ParkedVehicle => "parked_vehicles",
            PointClass::Static => "static",
        }
    }
}

impl ObjectBox {
    /// A vehicle (the nuScenes `vehicle.*` categories, bicycles and motorcycles included).
    pub fn is_vehicle(&self) -> bool {
        self.category.starts_with("vehicle.")
    }

    /// Its planar speed, m/s; 0 for an object annotated once.
    pub fn speed_mps(&self) -> f64 {
        self.velocity.map_or(0.0, |[vx, vy]| vx.hypot(vy))
    }

    pub fn is_moving(&self) -> bool {
        self.speed_mps() > MOVING_SPEED_MPS
    }

    /// The class of the points on it, when it is a vehicle.
    pub fn vehicle_class(&self) -> Option<PointClass> {
        self.is_vehicle().then(|| {
            if self.is_moving() {
                PointClass::MovingVehicle
            } else {
                PointClass::ParkedVehicle
            }
        })
    }

    /// The box seen from another frame: `target_from_global · global_from_box`.
    pub fn moved(&self, target_from_global: &Pose) -> ObjectBox {
        ObjectBox {
            global_from_box: *target_from_global * self.global_from_box,
            ..self.clone()
        }
    }

    /// Whether `point` (in the frame the box is expressed in) lies in the box grown by
    /// `margin` metres on every side but the bottom, which is raised by `lift`: a point on
    /// the ground under a car is the road's, not the car's.
    pub fn contains(&self, point: DVec3, margin: f64, lift: f64) -> bool {
        let local = self.global_from_box.inverse().transform_point3(point);
        let [width, length, height] = self.size;
        local.x.abs() <= 0.5 * length + margin
            && local.y.abs() <= 0.5 * width + margin
            && local.z >= -0.5 * height + lift
            && local.z <= 0.5 * height + margin
    }

    /// Its centre in the frame it is expressed in.
    pub fn center(&self) -> DVec3 {
        self.global_from_box.translation
    }
}

/// The class of `point`: the class of the first vehicle box (grown by `margin`, its bottom
/// raised by `lift`) that holds it, else static.
pub fn classify_point(boxes: &[ObjectBox], point: DVec3, margin: f64, lift: f64) -> PointClass {
    boxes
        .iter()
        .filter_map(|b| Some((b.vehicle_class()?, b)))
        .find(|(_, b)| b.contains(point, margin, lift))
        .map_or(PointClass::Static, |(class, _)| class)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DQuat;

    fn car(x: f64, y: f64, yaw: f64, velocity: Option<[f64; 2]>) -> ObjectBox {
        ObjectBox {
            attributes: Vec::new(),
            num_pts: 1,
            instance_token: format!("car@{x},{y}"),
            category: "vehicle.car".into(),
            global_from_box: Pose::from_rotation_translation(
                DQuat::from_rotation_z(yaw),
                DVec3::new(x, y, 0.75),
            ),
            size: [2.0, 4.0, 1.5],
            velocity,
        }
    }

    #[test]
    fn a_box_holds_what_lies_inside_its_rotated_extent_and_not_the_road_under_it() {
        // A 4 m long car turned 90°: its length runs along y.
        let b = car(10.0, 0.0, std::f64::consts::FRAC_PI_2, None);
        assert!(b.contains(DVec3::new(10.0, 1.9, 1.0), 0.0, 0.0));
        assert!(
            !b.contains(DVec3::new(11.9, 0.0, 1.0), 0.0, 0.0),
            "1.9 m across a 2 m wide car"
        );
        assert!(
            b.contains(DVec3::new(11.1, 0.0, 1.0), 0.2, 0.0),
            "inside the margin"
        );
        // The road under it (z = 0.02, the box's bottom at 0) is not the car's once the bottom
        // is lifted by 0.1 m; its roof (z = 1.6 against a top at 1.5) is, within the margin.
        assert!(!b.contains(DVec3::new(10.0, 0.0, 0.02), 0.2, 0.1));
        assert!(b.contains(DVec3::new(10.0, 0.0, 1.6), 0.2, 0.1));
    }

    #[test]
    fn speed_decides_moving_and_category_decides_vehicle() {
        let moving = car(0.0, 0.0, 0.0, Some([3.0, 4.0]));
        assert_eq!(moving.speed_mps(), 5.0);
        assert_eq!(moving.vehicle_class(), Some(PointClass::MovingVehicle));
        let creeping = car(0.0, 0.0, 0.0, Some([0.3, 0.3]));
        assert_eq!(creeping.vehicle_class(), Some(PointClass::ParkedVehicle));
        assert_eq!(
            car(0.0, 0.0, 0.0, None).vehicle_class(),
            Some(PointClass::ParkedVehicle)
        );
        let walker = ObjectBox {
            category: "human.pedestrian.adult".into(),
            ..moving.clone()
        };
        assert_eq!(walker.vehicle_class(), None);
        let boxes = [walker, moving];
        assert_eq!(
            classify_point(&boxes, DVec3::new(0.0, 0.0, 1.0), 0.2, 0.1),
            PointClass::MovingVehicle,
            "a walker's box in front does not hide the car"
        );
        assert_eq!(
            classify_point(&boxes, DVec3::new(5.0, 0.0, 1.0), 0.2, 0.1),
            PointClass::Static
        );
    }

    #[test]
    fn moving_a_box_moves_its_centre_and_keeps_its_extent() {
        let b = car(10.0, 5.0, 0.0, None);
        // The ego at (10, 0), turned 90°: the car is 5 m ahead of it.
        let global_from_ego = Pose::from_rotation_translation(
            DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2),
            DVec3::new(10.0, 0.0, 0.0),
        );
        let seen = b.moved(&global_from_ego.inverse());
        assert!((seen.center() - DVec3::new(5.0, 0.0, 0.75)).length() < 1e-9);
        // Its 4 m length, along global x, now runs along the ego's -y / +y.
        assert!(seen.contains(DVec3::new(5.0, 1.9, 1.0), 0.0, 0.0));
        assert!(!seen.contains(DVec3::new(6.9, 0.0, 1.0), 0.0, 0.0));
    }
}
