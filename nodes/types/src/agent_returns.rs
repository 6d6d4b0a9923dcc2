//! A detected agent's motion read from its own LiDAR returns, not from where the detector's
//! 2.5 m cells put it.
//!
//! The tiny detectors place a moving car within about 0.7 m (one standard deviation along and
//! across it), and the error of one frame carries into the next for a second or more: a
//! velocity read from those positions is one to three m/s off, however many frames a track
//! holds. The sweep the detector was given holds the car itself, to centimetres. Each agent's
//! returns are those inside its box grown by a margin (the detector's error), above its bottom
//! so the road under it does not count. The returns of two linked frames are registered onto
//! each other (iterative closest points, translation only, the worst fifth of the pairs left
//! out): the sides the sensor sees change little in half a second, so the shift that lays one
//! frame's returns onto the next is the car's motion, where the difference of their means would
//! take a side that comes into view for motion.

use glam::DVec3;

use crate::agent_track::{AgentTrack, TrackRule, track_agents};
use crate::detected_agents::{DetectedAgent, FrameDetections};

/// Which returns re-centre an agent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ReturnsRule {
    /// How far outside the detected box a return may lie, m (the detector's error).
    pub margin_m: f64,
    /// Returns lower than this above the box's bottom are the road, m.
    pub above_bottom_m: f64,
    /// Fewer returns than this leave the agent where the detector put it.
    pub min_returns: usize,
}

/// The (x, y) of the returns (`points`, in the agent's frame) inside `agent`'s box grown by
/// the rule's margin, above its bottom.
pub fn returns_of(agent: &DetectedAgent, points: &[[f32; 3]], rule: &ReturnsRule) -> Vec<[f64; 2]> {
    let [cx, cy, cz] = agent.centre;
    let [width, length, height] = agent.size;
    // The box's axes: length along the heading, width across it.
    let (sin, cos) = agent.yaw.sin_cos();
    let half_length = 0.5 * length + rule.margin_m;
    let half_width = 0.5 * width + rule.margin_m;
    let bottom = cz - 0.5 * height + rule.above_bottom_m;
    let top = cz + 0.5 * height + rule.margin_m;
    let reach = half_length.hypot(half_width);
    let mut inside = Vec::new();
    for p in points {
        let (x, y, z) = (f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
        let (dx, dy) = (x - cx, y - cy);
        if dx.abs() > reach || dy.abs() > reach || z < bottom || z > top {
            continue;
        }
        let along = dx * cos + dy * sin;
        let across = -dx * sin + dy * cos;
        if along.abs() <= half_length && across.abs() <= half_width {
            inside.push([x, y]);
        }
    }
    inside
}

fn mean(points: &[[f64; 2]]) -> [f64; 2] {
    let n = points.len().max(1) as f64;
    let (x, y) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0], y + p[1]));
    [x / n, y / n]
}

/// The share of a registration's nearest pairs that move it and score it: the rest (returns of
/// a side one frame sees and the other does not) are left out.
const KEPT_PAIRS: f64 = 0.8;

/// For each of `moving` shifted by `t`, the distance to its nearest of `fixed` and which.
fn nearest(moving: &[[f64; 2]], fixed: &[[f64; 2]], t: [f64; 2]) -> Vec<(f64, usize)> {
    moving
        .iter()
        .map(|p| {
            let q = [p[0] + t[0], p[1] + t[1]];
            fixed
                .iter()
                .enumerate()
                .map(|(j, f)| ((f[0] - q[0]).hypot(f[1] - q[1]), j))
                .min_by(|a, b| a.0.total_cmp(&b.0))
                .unwrap_or((f64::INFINITY, 0))
        })
        .collect()
}

/// The translation `t` that lays `before` (an agent's returns in one frame) onto `after` (its
/// returns in a later frame, the same coordinates): iterative closest points, translation only,
/// each step the mean offset of the nearest 80% of pairs. It starts from no motion and from
/// the returns' mean offset, and keeps the start whose end fits better (the mean squared
/// distance of the pairs kept): a parked car's returns are found where they were, a passing car's where
/// the mean offset puts them. `None` without returns on either side.
pub fn register_returns(before: &[[f64; 2]], after: &[[f64; 2]]) -> Option<[f64; 2]> {
    if before.is_empty() || after.is_empty() {
        return None;
    }
    let (b, a) = (mean(before), mean(after));
    // The nearest pairs at `t`, the 80% nearest kept: their distances and offsets.
    let kept_pairs = |t: [f64; 2]| {
        let mut pairs: Vec<(f64, [f64; 2])> = nearest(before, after, t)
            .into_iter()
            .zip(before)
            .map(|((d, j), p)| (d, [after[j][0] - p[0], after[j][1] - p[1]]))
            .collect();
        pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
        let keep = ((KEPT_PAIRS * pairs.len() as f64).ceil() as usize).clamp(1, pairs.len());
        pairs.truncate(keep);
        pairs
    };
    let fit = |start: [f64; 2]| {
        let mut t = start;
        for _ in 0..30 {
            let pairs = kept_pairs(t);
            let n = pairs.len() as f64;
            let next = pairs
                .iter()
                .fold([0.0, 0.0], |s, (_, o)| [s[0] + o[0] / n, s[1] + o[1] / n]);
            let step = (next[0] - t[0]).hypot(next[1] - t[1]);
            t = next;
            if step < 1e-4 {
                break;
            }
        }
        // Scored as it was fitted: the mean squared distance of the kept pairs.
        let pairs = kept_pairs(t);
        let residual = pairs.iter().map(|(d, _)| d * d).sum::<f64>() / pairs.len() as f64;
        (t, residual)
    };
    let (standing, standing_residual) = fit([0.0, 0.0]);
    let (moved, moved_residual) = fit([a[0] - b[0], a[1] - b[1]]);
    Some(if moved_residual < standing_residual {
        moved
    } else {
        standing
    })
}

/// A track's velocity read from its agent's returns instead of the detector's positions:
/// `returns[k]` are the agent's returns in the track's k-th frame (newest first, one common
/// frame for all). The current frame's returns' mean anchors the track; each earlier position
/// is the later one less the registration of the earlier returns onto the later ones. The
/// track ends at the first frame with fewer than `min_returns` returns; the velocity is the
/// least-squares slope of what is left (`AgentTrack::velocity`), in that common frame. `None`
/// when the current frame or the one before it has too few returns.
pub fn track_velocity_on_returns(
    track: &AgentTrack,
    returns: &[&[[f64; 2]]],
    min_returns: usize,
) -> Option<[f64; 2]> {
    let enough = |r: &[[f64; 2]]| r.len() >= min_returns.max(1);
    let current = *returns.first().filter(|r| enough(r))?;
    let mut anchored = AgentTrack {
        positions: vec![mean(current)],
        seconds_before: vec![0.0],
        agents: vec![*track.agents.first()?],
    };
    for k in 1..track.positions.len().min(returns.len()) {
        if !enough(returns[k]) {
            break;
        }
        let t = register_returns(returns[k], returns[k - 1])?;
        let later = anchored.positions[k - 1];
        anchored.positions.push([later[0] - t[0], later[1] - t[1]]);
        anchored.seconds_before.push(track.seconds_before[k]);
        anchored.agents.push(track.agents[k]);
    }
    anchored.velocity()
}

/// Every agent's returns in `detections` (`returns_of`, `ego_points` in the frame's ego frame),
/// moved into the global frame, where the frames of a track meet.
pub fn frame_returns(
    detections: &FrameDetections,
    ego_points: &[[f32; 3]],
    rule: &ReturnsRule,
) -> Vec<Vec<[f64; 2]>> {
    let global_from_ego = detections.meta.global_from_ego;
    detections
        .agents
        .iter()
        .map(|agent| {
            returns_of(agent, ego_points, rule)
                .into_iter()
                .map(|[x, y]| {
                    let g = global_from_ego.transform_point3(DVec3::new(x, y, 0.0));
                    [g.x, g.y]
                })
                .collect()
        })
        .collect()
}

/// One frame's detections with every agent's returns (`frame_returns`).
#[derive(Clone, Copy, Debug)]
pub struct DetectionsWithReturns<'a> {
    pub detections: &'a FrameDetections,
    pub returns: &'a [Vec<[f64; 2]>],
}

/// The velocity of each of `current`'s agents from its returns (`track_velocity_on_returns`),
/// linked to the agents of `earlier` (its scene's frames before, newest first) by `rule`, in
/// the current ego frame; `None` for an agent without a track or without returns enough.
pub fn velocities_on_returns(
    current: DetectionsWithReturns<'_>,
    earlier: &[DetectionsWithReturns<'_>],
    rule: &TrackRule,
    min_returns: usize,
) -> Vec<Option<[f64; 2]>> {
    let earlier_detections: Vec<&FrameDetections> = earlier.iter().map(|e| e.detections).collect();
    let ego_from_global = current.detections.meta.global_from_ego.inverse();
    track_agents(current.detections, &earlier_detections, rule)
        .iter()
        .map(|track| {
            // The track's k-th frame is `earlier[k − 1]`: a track ends where a link fails.
            let returns: Vec<&[[f64; 2]]> = track
                .agents
                .iter()
                .enumerate()
                .map(|(k, &agent)| {
                    let frame = if k == 0 {
                        current
                    } else {
                        *earlier.get(k - 1)?
                    };
                    frame.returns.get(agent).map(Vec::as_slice)
                })
                .collect::<Option<_>>()?;
            let [vx, vy] = track_velocity_on_returns(track, &returns, min_returns)?;
            let v = ego_from_global.transform_vector3(DVec3::new(vx, vy, 0.0));
            Some([v.x, v.y])
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn car(x: f64, y: f64, yaw: f64) -> DetectedAgent {
        DetectedAgent {
            detection_name: "car".into(),
            score: 0.9,
            centre: [x, y, 0.8],
            size: [2.0, 4.0, 1.6],
            yaw,
            velocity: [0.0, 0.0],
            modes: Vec::new(),
        }
    }

    const RULE: ReturnsRule = ReturnsRule {
        margin_m: 0.5,
        above_bottom_m: 0.3,
        min_returns: 3,
    };

    #[test]
    fn an_agents_returns_are_those_in_its_grown_box_above_the_road() {
        // Detected at (10, 0) heading +x (4 m long, 2 m wide: |x − 10| ≤ 2.5, |y| ≤ 1.5 with
        // the margin). Its returns: four at (10.4 ± 0.5, 0.2 ± 0.5), 1 m up. A road return
        // under it (z 0.1, under the bottom 0 + 0.3), one too high (z 3), and a neighbour's at
        // y = 2 (outside 1.5) do not count.
        let mut points = vec![
            [9.9, -0.3, 1.0],
            [10.9, -0.3, 1.0],
            [9.9, 0.7, 1.0],
            [10.9, 0.7, 1.0],
        ];
        points.extend([[10.0, 0.0, 0.1], [10.0, 0.0, 3.0], [10.0, 2.0, 1.0]]);
        let returns = returns_of(&car(10.0, 0.0, 0.0), &points, &RULE);
        assert_eq!(returns.len(), 4);
        let centre = mean(&returns);
        assert!(
            (centre[0] - 10.4).abs() < 1e-6 && (centre[1] - 0.2).abs() < 1e-6,
            "{centre:?}"
        );
        // Turned a quarter, the box is 2 m along x and 4 m along y: the neighbour at y = 2
        // now counts, the return at x = 10.9 still does (|x − 10| ≤ 1.5).
        let turned = returns_of(&car(10.0, 0.0, std::f64::consts::FRAC_PI_2), &points, &RULE);
        assert_eq!(turned.len(), 5);
        let turned = mean(&turned);
        let mean_y = (-0.3 - 0.3 + 0.7 + 0.7 + 2.0) / 5.0;
        assert!((turned[1] - mean_y).abs() < 1e-6, "{turned:?}");
    }

    /// A car's corner as a LiDAR sees it: its 4 m side along x and its 2 m back along y, a
    /// return every 0.25 m (25 returns), shifted by `by`.
    fn corner(by: [f64; 2]) -> Vec<[f64; 2]> {
        let side = (0..=16).map(|i| [0.25 * f64::from(i), 0.0]);
        let back = (1..=8).map(|i| [0.0, 0.25 * f64::from(i)]);
        side.chain(back)
            .map(|p| [p[0] + by[0], p[1] + by[1]])
            .collect()
    }

    #[test]
    fn registration_finds_a_passing_cars_motion_and_a_parked_cars_stillness() {
        // Driven 3 m along and 0.5 m across: every return moved alike.
        let t = register_returns(&corner([10.0, 5.0]), &corner([13.0, 5.5])).expect("returns");
        assert!(
            (t[0] - 3.0).abs() < 1e-9 && (t[1] - 0.5).abs() < 1e-9,
            "{t:?}"
        );
        // Parked, but the later frame misses the side's far metre (four returns): the mean of
        // the returns moves from (1.36, 0.36) to (19.5/21, 9/21) = (0.93, 0.43) m past the
        // corner, 0.44 m, a car that seems to drive at 0.9 m/s over 0.5 s. The registration
        // keeps it where it was: the four unmatched pairs are within the 20% it leaves out.
        let before = corner([10.0, 5.0]);
        let after: Vec<[f64; 2]> = before.iter().copied().filter(|p| p[0] < 13.1).collect();
        assert_eq!(after.len(), 21);
        let (b, a) = (mean(&before), mean(&after));
        assert!(((a[0] - b[0]).hypot(a[1] - b[1]) - 0.437).abs() < 1e-3);
        let t = register_returns(&before, &after).expect("returns");
        assert!(t[0].hypot(t[1]) < 1e-9, "{t:?}");
        assert_eq!(register_returns(&before, &[]), None);
        assert_eq!(register_returns(&[], &after), None);
    }

    #[test]
    fn a_tracks_velocity_on_returns_reads_the_registrations_and_stops_at_a_frame_without() {
        // A car at 10 m/s along +x: its returns 5 m further on every half second, newest
        // first. The detector's positions (the track's) are off by decimetres and do not count.
        let track = AgentTrack {
            positions: vec![[20.4, 0.3], [14.8, -0.2], [10.3, 0.1]],
            seconds_before: vec![0.0, 0.5, 1.0],
            agents: vec![0, 2, 1],
        };
        let frames = [
            corner([20.0, 0.0]),
            corner([15.0, 0.0]),
            corner([10.0, 0.0]),
        ];
        let all: Vec<&[[f64; 2]]> = frames.iter().map(Vec::as_slice).collect();
        let v = track_velocity_on_returns(&track, &all, 3).expect("three frames");
        assert!((v[0] - 10.0).abs() < 1e-9 && v[1].abs() < 1e-9, "{v:?}");
        // Without returns in the oldest frame the track ends a frame earlier: still 10 m/s.
        let two = [all[0], all[1], &[][..]];
        let v = track_velocity_on_returns(&track, &two, 3).expect("two frames");
        assert!((v[0] - 10.0).abs() < 1e-9, "{v:?}");
        // Without them in the frame before, or in the current frame, there is no velocity.
        assert_eq!(
            track_velocity_on_returns(&track, &[all[0], &[][..], all[2]], 3),
            None
        );
        assert_eq!(
            track_velocity_on_returns(&track, &[&[][..], all[1], all[2]], 3),
            None
        );
        // A track of one frame has none either.
        let alone = AgentTrack {
            positions: vec![[20.4, 0.3]],
            seconds_before: vec![0.0],
            agents: vec![0],
        };
        assert_eq!(track_velocity_on_returns(&alone, &all, 3), None);
    }

    #[test]
    fn velocities_come_from_the_returns_in_the_current_ego_frame_not_from_the_boxes() {
        use crate::agent_track::tests::{RULE as TRACK_RULE, frame};
        // The ego drives +x at 8 m/s (x = 0, then 4). A car drives +x at 10 m/s, its centre
        // from global (20, 1) to (25, 1); a car stands at global (32, 5). The detector puts the
        // driving car 0.3 m ahead, then 0.4 m behind (global 20.3, then 24.6: 8.6 m/s) and the
        // parked one 0.2 m off; their returns, each car's corner, are where the cars are.
        let in_ego = |ego_x: f64, corners: &[[f64; 2]]| -> Vec<[f32; 3]> {
            corners
                .iter()
                .flat_map(|&at| corner(at))
                .map(|p| [(p[0] - ego_x) as f32, p[1] as f32, 1.0])
                .collect()
        };
        let before = frame(0.0, 0.0, vec![car(20.3, 1.0, 0.0), car(32.0, 5.0, 0.0)]);
        let now = frame(0.5, 4.0, vec![car(20.6, 1.0, 0.0), car(28.2, 5.2, 0.0)]);
        let returns_before =
            frame_returns(&before, &in_ego(0.0, &[[18.0, 0.0], [30.0, 4.0]]), &RULE);
        let returns_now = frame_returns(&now, &in_ego(4.0, &[[23.0, 0.0], [30.0, 4.0]]), &RULE);
        // Each car's box holds its own 25 returns (within the margin of 0.5 m of every box).
        assert!(
            returns_now
                .iter()
                .chain(&returns_before)
                .all(|r| r.len() == 25)
        );
        let rule = TRACK_RULE;
        let velocities = velocities_on_returns(
            DetectionsWithReturns {
                detections: &now,
                returns: &returns_now,
            },
            &[DetectionsWithReturns {
                detections: &before,
                returns: &returns_before,
            }],
            &rule,
            3,
        );
        let driving = velocities[0].expect("tracked");
        assert!(
            (driving[0] - 10.0).abs() < 1e-9 && driving[1].abs() < 1e-9,
            "{driving:?}"
        );
        let parked = velocities[1].expect("tracked");
        assert!(parked[0].hypot(parked[1]) < 1e-9, "{parked:?}");
        // Without an earlier frame there is no track, so no velocity.
        let alone = velocities_on_returns(
            DetectionsWithReturns {
                detections: &now,
                returns: &returns_now,
            },
            &[],
            &rule,
            3,
        );
        assert_eq!(alone, vec![None, None]);
    }
}
