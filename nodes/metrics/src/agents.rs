//! Agent-level scores of a forecast sweep. Whole-scene Chamfer is dominated by the road and the
//! buildings; a world model is judged by the other road users. So the true sweep's points are
//! split by the dataset's boxes into those on moving vehicles, on parked vehicles and the
//! static rest, and for each class:
//!
//! - **recall at r** (0.5 m, 1 m): the share of true points with a forecast point within r;
//!   for moving vehicles also counting only forecast points above the ground, so that a
//!   forecast cannot score a car with the road under it;
//! - **one-sided Chamfer**: the mean squared distance from each true point to the forecast
//!   (m², as the Chamfer distance);
//!
//! and for the moving vehicles:
//!
//! - **precision in their boxes**: of the forecast points above the ground inside the moving
//!   vehicles' true boxes (grown by `BOX_MARGIN_M`), the share within 0.5 m of a true point on
//!   a moving vehicle;
//! - **displacement**: per moving vehicle, the distance in the ground plane between the centroid
//!   of the forecast's points above the ground near its true box (grown by
//!   `SEARCH_MARGIN_M`) and the centroid of its true points; a vehicle with no forecast point
//!   there is missed.
//!
//! Scores are kept as sums, so that they pool over contexts and scenes.

use std::collections::BTreeMap;

use bevworld_types::{ObjectBox, PointClass, SensorFrame, classify_point};
use glam::DVec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};

use crate::chamfer::Roi;

/// How far outside its box a point still counts as the vehicle's: the returns lie on the
/// box's faces, and annotations are a few centimetres off.
pub const BOX_MARGIN_M: f64 = 0.2;
/// The box's bottom is raised by this much, so that the road under a vehicle stays static.
pub const BOX_LIFT_M: f64 = 0.1;
/// Points higher than this in the ego frame (whose origin is on the ground) are above it.
pub const ABOVE_GROUND_M: f64 = 0.25;
/// How far around a moving vehicle's true box its forecast points are looked for.
pub const SEARCH_MARGIN_M: f64 = 1.0;
/// The recall radii, metres.
pub const NEAR_M: f64 = 0.5;
pub const FAR_M: f64 = 1.0;

/// A true sweep split by class: its scene points in the ego frame, inside the ROI, each with
/// its class, and the vehicles' boxes in the same frame.
#[derive(Clone, Debug, Default)]
pub struct SplitTruth {
    pub points: Vec<[f64; 3]>,
    pub classes: Vec<PointClass>,
    pub vehicles: Vec<ObjectBox>,
}

impl SplitTruth {
    /// Each point classed by the vehicles' boxes (ego frame), with the box margin and lift.
    pub fn new(points: Vec<[f64; 3]>, vehicles: Vec<ObjectBox>) -> Self {
        let classes = points
            .iter()
            .map(|p| classify_point(&vehicles, DVec3::from_array(*p), BOX_MARGIN_M, BOX_LIFT_M))
            .collect();
        Self {
            points,
            classes,
            vehicles,
        }
    }
}

/// The frame's annotated vehicles, moved into its LiDAR-time ego frame.
pub fn vehicles_in_ego_frame(frame: &SensorFrame) -> Vec<ObjectBox> {
    let ego_from_global = frame.lidar.global_from_ego.inverse();
    frame
        .boxes
        .iter()
        .filter(|b| b.is_vehicle())
        .map(|b| b.moved(&ego_from_global))
        .collect()
}

/// Splits a logged frame by its annotated boxes. A frame without boxes is all static.
pub fn split_truth(frame: &SensorFrame, roi: &Roi) -> SplitTruth {
    let vehicles = vehicles_in_ego_frame(frame);
    let points: Vec<[f64; 3]> = frame
        .lidar
        .scene_ego_points()
        .into_iter()
        .map(|p| [p[0].into(), p[1].into(), p[2].into()])
        .filter(|p| roi.contains(p))
        .collect();
    SplitTruth::new(points, vehicles)
}

/// The sums of one class.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ClassSums {
    pub points: u64,
    pub within_near: u64,
    pub within_far: u64,
    /// Within `NEAR_M` of a forecast point above the ground.
    pub within_near_above_ground: u64,
    /// Σ squared distance to the nearest forecast point, m².
    pub squared: f64,
}

impl ClassSums {
    fn add(&mut self, other: &ClassSums) {
        self.points += other.points;
        self.within_near += other.within_near;
        self.within_far += other.within_far;
        self.within_near_above_ground += other.within_near_above_ground;
        self.squared += other.squared;
    }

    fn share(&self, count: u64) -> Option<f64> {
        (self.points > 0).then(|| count as f64 / self.points as f64)
    }

    pub fn recall_near(&self) -> Option<f64> {
        self.share(self.within_near)
    }

    pub fn recall_far(&self) -> Option<f64> {
        self.share(self.within_far)
    }

    pub fn recall_near_above_ground(&self) -> Option<f64> {
        self.share(self.within_near_above_ground)
    }

    /// The one-sided Chamfer distance from the truth to the forecast, m².
    pub fn chamfer_to_forecast(&self) -> Option<f64> {
        (self.points > 0).then(|| self.squared / self.points as f64)
    }
}

/// The sums of one forecast sweep against its split truth, or of many pooled.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AgentSums {
    /// In `PointClass::ALL` order.
    pub classes: [ClassSums; 3],
    /// Forecast points above the ground inside the moving vehicles' grown boxes, and those of
    /// them within `NEAR_M` of a true point on a moving vehicle.
    pub in_moving_boxes: u64,
    pub in_moving_boxes_near_truth: u64,
    /// Moving vehicles with true points, those the forecast put points near, and the sum of
    /// their displacements, m.
    pub moving_agents: u64,
    pub moving_agents_found: u64,
    pub displacement_sum_m: f64,
}

impl AgentSums {
    pub fn class(&self, class: PointClass) -> &ClassSums {
        &self.classes[class_index(class)]
    }

    pub fn add(&mut self, other: &AgentSums) {
        for (mine, theirs) in self.classes.iter_mut().zip(&other.classes) {
            mine.add(theirs);
        }
        self.in_moving_boxes += other.in_moving_boxes;
        self.in_moving_boxes_near_truth += other.in_moving_boxes_near_truth;
        self.moving_agents += other.moving_agents;
        self.moving_agents_found += other.moving_agents_found;
        self.displacement_sum_m += other.displacement_sum_m;
    }

    /// The share of forecast points in the moving boxes that lie on a moving vehicle.
    pub fn precision_in_moving_boxes(&self) -> Option<f64> {
        (self.in_moving_boxes > 0)
            .then(|| self.in_moving_boxes_near_truth as f64 / self.in_moving_boxes as f64)
    }

    /// The mean displacement of the moving vehicles the forecast put points near, m.
    pub fn displacement_m(&self) -> Option<f64> {
        (self.moving_agents_found > 0)
            .then(|| self.displacement_sum_m / self.moving_agents_found as f64)
    }

    /// The share of moving vehicles with no forecast point near them.
    pub fn moving_agents_missed(&self) -> Option<f64> {
        (self.moving_agents > 0).then(|| {
            (self.moving_agents - self.moving_agents_found) as f64 / self.moving_agents as f64
        })
    }
}

fn class_index(class: PointClass) -> usize {
    match class {
        PointClass::MovingVehicle => 0,
        PointClass::ParkedVehicle => 1,
        PointClass::Static => 2,
    }
}

fn tree(points: &[[f64; 3]]) -> Option<ImmutableKdTree<f64, 3>> {
    (!points.is_empty())
        .then(|| ImmutableKdTree::new_from_slice(points))
        .and_then(Result::ok)
}

/// The squared distance to the nearest point of `tree`; infinite when there is none.
fn nearest_squared(tree: Option<&ImmutableKdTree<f64, 3>>, query: &[f64; 3]) -> f64 {
    tree.map_or(f64::INFINITY, |t| {
        t.query(query)
            .nearest_one::<SquaredEuclidean<f64>>()
            .execute()
            .distance
    })
}

/// Scores one forecast sweep (points in the truth's ego frame) against its split truth. The
/// forecast is cut to the same ROI as the truth.
pub fn score(truth: &SplitTruth, forecast: &[[f64; 3]], roi: &Roi) -> AgentSums {
    let forecast: Vec<[f64; 3]> = forecast
        .iter()
        .copied()
        .filter(|p| roi.contains(p))
        .collect();
    let above: Vec<[f64; 3]> = forecast
        .iter()
        .copied()
        .filter(|p| p[2] > ABOVE_GROUND_M)
        .collect();
    let (all_tree, above_tree) = (tree(&forecast), tree(&above));
    let mut sums = AgentSums::default();
    for (point, class) in truth.points.iter().zip(&truth.classes) {
        let squared = nearest_squared(all_tree.as_ref(), point);
        let sums = &mut sums.classes[class_index(*class)];
        sums.points += 1;
        // A forecast with no point has nothing near: the squared distance stays out of the
        // sum (it would be infinite), and recall counts it a miss.
        if squared.is_finite() {
            sums.squared += squared;
        }
        sums.within_near += u64::from(squared <= NEAR_M * NEAR_M);
        sums.within_far += u64::from(squared <= FAR_M * FAR_M);
        let above = nearest_squared(above_tree.as_ref(), point);
        sums.within_near_above_ground += u64::from(above <= NEAR_M * NEAR_M);
    }
    let moving_boxes: Vec<&ObjectBox> = truth
        .vehicles
        .iter()
        .filter(|b| b.vehicle_class() == Some(PointClass::MovingVehicle))
        .collect();
    let moving_truth: Vec<[f64; 3]> = truth
        .points
        .iter()
        .zip(&truth.classes)
        .filter(|(_, c)| **c == PointClass::MovingVehicle)
        .map(|(p, _)| *p)
        .collect();
    let moving_tree = tree(&moving_truth);
    for point in &above {
        let at = DVec3::from_array(*point);
        if moving_boxes
            .iter()
            .any(|b| b.contains(at, BOX_MARGIN_M, BOX_LIFT_M))
        {
            sums.in_moving_boxes += 1;
            let squared = nearest_squared(moving_tree.as_ref(), point);
            sums.in_moving_boxes_near_truth += u64::from(squared <= NEAR_M * NEAR_M);
        }
    }
    for vehicle in moving_boxes {
        let centroid = |points: &mut dyn Iterator<Item = DVec3>| -> Option<DVec3> {
            let (sum, count) = points.fold((DVec3::ZERO, 0usize), |(s, n), p| (s + p, n + 1));
            (count > 0).then(|| sum / count as f64)
        };
        let seen = centroid(
            &mut truth
                .points
                .iter()
                .map(|p| DVec3::from_array(*p))
                .filter(|p| vehicle.contains(*p, BOX_MARGIN_M, BOX_LIFT_M)),
        );
        // A vehicle the sweep did not see cannot be looked for.
        let Some(seen) = seen else {
            continue;
        };
        sums.moving_agents += 1;
        let forecast_there = centroid(
            &mut above
                .iter()
                .map(|p| DVec3::from_array(*p))
                .filter(|p| vehicle.contains(*p, SEARCH_MARGIN_M, BOX_LIFT_M)),
        );
        if let Some(there) = forecast_there {
            sums.moving_agents_found += 1;
            sums.displacement_sum_m += (there - seen).truncate().length();
        }
    }
    sums
}

/// Agent-level scores as JSON, for a forecast's cell and a reconstruction's summary alike: per
/// class the pooled recall, one-sided Chamfer and point count, with the spread over scenes of
/// each scene's pooled value; for the moving vehicles the precision in their boxes and the
/// displacement. `None` when no sweep was annotated.
pub fn agents_json(
    pooled: &AgentSums,
    by_scene: &BTreeMap<String, AgentSums>,
) -> Option<serde_json::Value> {
    if pooled.classes.iter().all(|c| c.points == 0) {
        return None;
    }
    let mut agents = serde_json::Map::new();
    for class in PointClass::ALL {
        let sums = pooled.class(class);
        if sums.points == 0 {
            continue;
        }
        // Each scene's pooled value, then their mean and population spread: "mean ± spread
        // over scenes", as the whole-scene Chamfer reports it.
        let over_scenes = |value: &dyn Fn(&ClassSums) -> Option<f64>| {
            let per_scene: Vec<f64> = by_scene
                .values()
                .filter_map(|s| value(s.class(class)))
                .collect();
            let mean = (!per_scene.is_empty())
                .then(|| per_scene.iter().sum::<f64>() / per_scene.len() as f64);
            serde_json::json!({
                "mean": mean,
                "std": crate::report_file::population_std(&per_scene),
            })
        };
        agents.insert(
            class.name().into(),
            serde_json::json!({
                "points": sums.points,
                "recall_0.5m": sums.recall_near(),
                "recall_1m": sums.recall_far(),
                "recall_0.5m_above_ground": sums.recall_near_above_ground(),
                "chamfer_to_forecast": sums.chamfer_to_forecast(),
                "over_scenes": {
                    "scenes": by_scene.len(),
                    "recall_0.5m": over_scenes(&|s| s.recall_near()),
                    "recall_1m": over_scenes(&|s| s.recall_far()),
                    "recall_0.5m_above_ground": over_scenes(&|s| s.recall_near_above_ground()),
                    "chamfer_to_forecast": over_scenes(&|s| s.chamfer_to_forecast()),
                },
            }),
        );
    }
    agents.insert(
        "moving_boxes".into(),
        serde_json::json!({
            "forecast_points": pooled.in_moving_boxes,
            "precision_0.5m": pooled.precision_in_moving_boxes(),
        }),
    );
    agents.insert(
        "moving_agents".into(),
        serde_json::json!({
            "agents": pooled.moving_agents,
            "missed": pooled.moving_agents_missed(),
            "displacement_m": pooled.displacement_m(),
        }),
    );
    Some(agents.into())
}

#[cfg(test)]
mod tests {
    use super::*;
    use bevworld_types::Pose;
    use glam::DQuat;

    fn car(x: f64, y: f64, speed: f64) -> ObjectBox {
        ObjectBox {
            attributes: Vec::new(),
            num_pts: 1,
            instance_token: format!("car{x}"),
            category: "vehicle.car".into(),
            global_from_box: Pose::from_rotation_translation(
                DQuat::IDENTITY,
                DVec3::new(x, y, 0.75),
            ),
            size: [2.0, 4.0, 1.5],
            velocity: Some([speed, 0.0]),
        }
    }

    /// A truth of 4 points on a moving car at x = 10, 2 on a parked car at x = 20 and 4 on the
    /// road (2 m apart, one under the moving car), split by hand.
    fn truth() -> SplitTruth {
        let vehicles = vec![car(10.0, 0.0, 5.0), car(20.0, 5.0, 0.0)];
        let points = vec![
            [8.0, 0.0, 1.0],
            [8.0, 0.5, 1.0],
            [8.0, -0.5, 1.0],
            [8.0, 0.0, 0.5],
            [18.0, 5.0, 1.0],
            [18.0, 5.5, 1.0],
            [30.0, 0.0, 0.0],
            [32.0, 0.0, 0.0],
            [34.0, 0.0, 0.0],
            [10.0, 0.0, 0.02],
        ];
        SplitTruth::new(points, vehicles)
    }

    #[test]
    fn points_are_split_by_the_boxes_and_the_road_under_a_car_stays_static() {
        use PointClass::*;
        assert_eq!(
            truth().classes,
            vec![
                MovingVehicle,
                MovingVehicle,
                MovingVehicle,
                MovingVehicle,
                ParkedVehicle,
                ParkedVehicle,
                Static,
                Static,
                Static,
                Static
            ]
        );
    }

    #[test]
    fn scores_on_hand_made_points_match_the_hand_computation() {
        let truth = truth();
        let roi = Roi {
            min: [-100.0, -100.0, -10.0],
            max: [100.0, 100.0, 10.0],
        };
        // The forecast: two points 0.25 m behind the moving car's rear face (one 1 m up, one
        // 0.125 m up, below the ground line), the parked car's points exactly, and the road
        // 0.75 m off. Offsets are powers of two, so the distances are exact.
        let forecast = vec![
            [8.25, 0.0, 1.0],
            [8.25, 0.0, 0.125],
            [18.0, 5.0, 1.0],
            [18.0, 5.5, 1.0],
            [30.75, 0.0, 0.0],
            [32.75, 0.0, 0.0],
            [34.75, 0.0, 0.0],
            [10.75, 0.0, 0.0],
        ];
        let sums = score(&truth, &forecast, &roi);
        let moving = sums.class(PointClass::MovingVehicle);
        // (8,0,1) is 0.25 m from (8.25,0,1): d² 0.0625. (8,±0.5,1) are √0.3125 = 0.56 m from
        // it. (8,0,0.5) is √(0.0625 + 0.140625) = 0.45 m from (8.25,0,0.125).
        assert_eq!(moving.points, 4);
        assert_eq!(moving.within_near, 2);
        assert_eq!(moving.within_far, 4);
        // Above the ground only (8.25,0,1) counts, and only (8,0,1) is within 0.5 m of it.
        assert_eq!(moving.within_near_above_ground, 1);
        let expected = 0.0625 + 0.3125 + 0.3125 + 0.203125;
        assert_eq!(moving.squared, expected);
        assert_eq!(moving.chamfer_to_forecast(), Some(expected / 4.0));
        assert_eq!(moving.recall_near(), Some(0.5));
        let parked = sums.class(PointClass::ParkedVehicle);
        assert_eq!((parked.points, parked.within_near), (2, 2));
        assert_eq!(parked.squared, 0.0);
        let road = sums.class(PointClass::Static);
        // The road points are 0.75 m from their forecast points ((10,0,0.02) from (10.75,0,0)).
        assert_eq!((road.points, road.within_near, road.within_far), (4, 0, 4));
        // In the moving car's grown box, above the ground: (8.25,0,1) only, 0.25 m from a
        // true moving point.
        assert_eq!(
            (sums.in_moving_boxes, sums.in_moving_boxes_near_truth),
            (1, 1)
        );
        assert_eq!(sums.precision_in_moving_boxes(), Some(1.0));
        // The moving car: its true points' centroid is (8, 0); the forecast's above-ground
        // points near its box are (8.25, 0, 1) alone: 0.25 m. The parked car is no agent.
        assert_eq!((sums.moving_agents, sums.moving_agents_found), (1, 1));
        assert_eq!(sums.displacement_m(), Some(0.25));
        assert_eq!(sums.moving_agents_missed(), Some(0.0));
    }

    #[test]
    fn an_empty_forecast_finds_nothing_and_pools_with_others() {
        let truth = truth();
        let roi = Roi {
            min: [-100.0, -100.0, -10.0],
            max: [100.0, 100.0, 10.0],
        };
        let empty = score(&truth, &[], &roi);
        let moving = empty.class(PointClass::MovingVehicle);
        assert_eq!((moving.points, moving.within_far), (4, 0));
        assert_eq!(empty.moving_agents_missed(), Some(1.0));
        assert_eq!(empty.displacement_m(), None);
        let exact = score(&truth, &truth.points, &roi);
        let mut pooled = empty.clone();
        pooled.add(&exact);
        assert_eq!(pooled.class(PointClass::MovingVehicle).points, 8);
        assert_eq!(
            pooled.class(PointClass::MovingVehicle).recall_far(),
            Some(0.5)
        );
    }
}
