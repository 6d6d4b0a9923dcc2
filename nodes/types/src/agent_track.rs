//! Velocities of detected agents from where the same agents were detected in earlier frames:
//! tracking by detection, as CenterPoint tracks (greedy matching of the closest pairs, one
//! frame back at a time), without its learnt velocity for the first step.
//!
//! A detector that sees one frame (or two frames warped onto each other at 2.5 m cells) gives
//! a velocity that is mostly noise or the median, a parked car's zero. Its positions are better
//! than that: a car detected 5 m further on half a second later has driven at 10 m/s, whatever
//! its velocity head says. Each of the current frame's agents is linked to the closest unlinked
//! agent of the same class in the frame before (at most `max_speed_mps` × Δt away), then, with
//! the velocity of that link, to the agent of the frame before that which lies within `gate_m`
//! of where the link puts it. Its velocity is the least-squares slope of its positions over
//! time, in the current ego frame.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::detected_agents::FrameDetections;

/// How agents are linked across frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackRule {
    /// Frames in a track, the current one included (2 or more).
    pub frames: usize,
    /// Fastest speed a first link may imply, m/s: it bounds the first link's distance.
    pub max_speed_mps: f64,
    /// How far from where a track's velocity puts it an earlier detection may lie, m.
    pub gate_m: f64,
    /// Detections scored under this are neither tracked nor linked to.
    pub min_score: f64,
}

/// How a graph node links agents across frames (`TrackRule`, with the node's score bar), and
/// the speed under which a track stands.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct TrackParams {
    /// Frames in a track, the current one included.
    #[serde(default = "default_track_frames")]
    pub frames: usize,
    /// Fastest speed a first link may imply, m/s.
    #[serde(default = "default_max_speed")]
    pub max_speed_mps: f64,
    /// How far from where the track's velocity puts it an earlier detection may lie, m.
    #[serde(default = "default_gate")]
    pub gate_m: f64,
    /// A track slower than this stands, m/s: a detector's positions jitter by decimetres, which
    /// a track of a parked car turns into a speed that would carry it metres by 3 s.
    #[serde(default = "default_min_speed")]
    pub min_speed_mps: f64,
}

impl TrackParams {
    /// The first field out of range, by name, with why.
    pub fn problem(&self) -> Option<(&'static str, String)> {
        if !(2..=16).contains(&self.frames) {
            return Some(("frames", format!("{} must lie in 2..=16", self.frames)));
        }
        if !(self.max_speed_mps.is_finite() && self.max_speed_mps > 0.0) {
            let message = format!("{} must be a speed > 0 m/s", self.max_speed_mps);
            return Some(("max_speed_mps", message));
        }
        if !(self.gate_m.is_finite() && self.gate_m > 0.0) {
            return Some((
                "gate_m",
                format!("{} must be a distance > 0 m", self.gate_m),
            ));
        }
        if !(self.min_speed_mps.is_finite() && self.min_speed_mps >= 0.0) {
            let message = format!("{} must be a speed ≥ 0 m/s", self.min_speed_mps);
            return Some(("min_speed_mps", message));
        }
        None
    }

    /// The tracker's rule, with the node's score bar.
    pub fn rule(&self, min_score: f64) -> TrackRule {
        TrackRule {
            frames: self.frames,
            max_speed_mps: self.max_speed_mps,
            gate_m: self.gate_m,
            min_score,
        }
    }
}

impl Default for TrackParams {
    fn default() -> Self {
        Self {
            frames: default_track_frames(),
            max_speed_mps: default_max_speed(),
            gate_m: default_gate(),
            min_speed_mps: default_min_speed(),
        }
    }
}

fn default_track_frames() -> usize {
    3
}
fn default_max_speed() -> f64 {
    20.0
}
fn default_gate() -> f64 {
    2.0
}
fn default_min_speed() -> f64 {
    2.0
}

/// One current agent's track: its positions (x, y) in the current ego frame, newest first,
/// their times, seconds before the current frame (0 first), and the agent it is in each of
/// those frames (its index in the frame's `agents`: the current frame's first, then each
/// earlier frame's, as `track_agents` was given them).
#[derive(Clone, Debug, PartialEq)]
pub struct AgentTrack {
    pub positions: Vec<[f64; 2]>,
    pub seconds_before: Vec<f64>,
    pub agents: Vec<usize>,
}

impl AgentTrack {
    /// The least-squares velocity of its positions over time, m/s; `None` with one position.
    pub fn velocity(&self) -> Option<[f64; 2]> {
        let n = self.positions.len();
        if n < 2 {
            return None;
        }
        // Time runs forward: t = −seconds_before.
        let times: Vec<f64> = self.seconds_before.iter().map(|s| -s).collect();
        let mean_t = times.iter().sum::<f64>() / n as f64;
        let variance: f64 = times.iter().map(|t| (t - mean_t).powi(2)).sum();
        if variance <= 0.0 {
            return None;
        }
        let slope = |axis: usize| {
            let mean = self.positions.iter().map(|p| p[axis]).sum::<f64>() / n as f64;
            times
                .iter()
                .zip(&self.positions)
                .map(|(t, p)| (t - mean_t) * (p[axis] - mean))
                .sum::<f64>()
                / variance
        };
        Some([slope(0), slope(1)])
    }
}

/// The tracks of `current`'s agents (one per agent, in its order; a track of the agent alone
/// where it is unscored or unmatched) through `earlier`, newest first. Earlier frames must
/// precede the current one; a frame of another scene or not earlier ends the tracks there.
pub fn track_agents(
    current: &FrameDetections,
    earlier: &[&FrameDetections],
    rule: &TrackRule,
) -> Vec<AgentTrack> {
    let mut tracks: Vec<AgentTrack> = current
        .agents
        .iter()
        .enumerate()
        .map(|(i, a)| AgentTrack {
            positions: vec![[a.centre[0], a.centre[1]]],
            seconds_before: vec![0.0],
            agents: vec![i],
        })
        .collect();
    let tracked: Vec<bool> = current
        .agents
        .iter()
        .map(|a| a.score >= rule.min_score)
        .collect();
    let current_from_global = current.meta.global_from_ego.inverse();
    // Which tracks reached the previous frame: only those go on.
    let mut alive = tracked.clone();
    for frame in earlier.iter().take(rule.frames.saturating_sub(1)) {
        if frame.meta.scene_name != current.meta.scene_name
            || frame.meta.time_of_validity_us >= current.meta.time_of_validity_us
        {
            break;
        }
        let seconds_before =
            (current.meta.time_of_validity_us - frame.meta.time_of_validity_us) as f64 * 1e-6;
        let current_from_frame = current_from_global * frame.meta.global_from_ego;
        let candidates: Vec<(usize, [f64; 2])> = frame
            .agents
            .iter()
            .enumerate()
            .filter(|(_, a)| a.score >= rule.min_score)
            .map(|(j, a)| {
                let p = current_from_frame.transform_point3(DVec3::from_array(a.centre));
                (j, [p.x, p.y])
            })
            .collect();
        // Every admissible pair, by its distance from where the track expects the agent.
        let mut pairs: Vec<(f64, usize, usize, [f64; 2])> = Vec::new();
        for (i, track) in tracks.iter().enumerate() {
            if !alive[i] {
                continue;
            }
            let name = &current.agents[i].detection_name;
            let last = track.positions[track.positions.len() - 1];
            let last_before = track.seconds_before[track.seconds_before.len() - 1];
            let dt = seconds_before - last_before;
            let (expected, gate) = match track.velocity() {
                Some(v) => ([last[0] - v[0] * dt, last[1] - v[1] * dt], rule.gate_m),
                None => (last, rule.max_speed_mps * dt),
            };
            for &(j, p) in &candidates {
                if &frame.agents[j].detection_name != name {
                    continue;
                }
                let distance = (p[0] - expected[0]).hypot(p[1] - expected[1]);
                if distance <= gate {
                    pairs.push((distance, i, j, p));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut linked_track = vec![false; tracks.len()];
        let mut linked_candidate = vec![false; frame.agents.len()];
        for (_, i, j, p) in pairs {
            if linked_track[i] || linked_candidate[j] {
                continue;
            }
            linked_track[i] = true;
            linked_candidate[j] = true;
            tracks[i].positions.push(p);
            tracks[i].seconds_before.push(seconds_before);
            tracks[i].agents.push(j);
        }
        for (a, linked) in alive.iter_mut().zip(&linked_track) {
            *a = *a && *linked;
        }
    }
    tracks
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bev::FrameMeta;
    use crate::detected_agents::DetectedAgent;
    use crate::pose::Pose;

    fn car(x: f64, y: f64, score: f64) -> DetectedAgent {
        DetectedAgent {
            detection_name: "car".into(),
            score,
            centre: [x, y, 0.8],
            size: [1.9, 4.5, 1.6],
            yaw: 0.0,
            velocity: [0.0, 0.0],
            modes: Vec::new(),
        }
    }

    /// A keyframe of scene "a" at `time_s`, the ego at (`ego_x`, 0), holding `agents`.
    pub(crate) fn frame(time_s: f64, ego_x: f64, agents: Vec<DetectedAgent>) -> FrameDetections {
        FrameDetections {
            meta: FrameMeta {
                sample_token: format!("s{time_s}"),
                frame_token: format!("f{time_s}"),
                scene_name: "a".into(),
                time_of_validity_us: (time_s * 1e6).round() as i64,
                global_from_ego: Pose::from_translation(DVec3::new(ego_x, 0.0, 0.0)),
                keyframe: true,
            },
            agents,
            interval_s: 0.5,
            model: "detector-tiny".into(),
            weights_hash: "d".into(),
        }
    }

    pub(crate) const RULE: TrackRule = TrackRule {
        frames: 3,
        max_speed_mps: 20.0,
        gate_m: 2.0,
        min_score: 0.3,
    };

    #[test]
    fn a_driving_car_beside_parked_ones_gets_its_speed_and_the_parked_ones_none() {
        // The ego drives +x at 8 m/s, so every earlier frame's centres sit 4 m further on per
        // half second in its own ego frame. A car drives +x at 10 m/s in the lane (y = 0),
        // passing parked cars at y = 3. Globally: the driving car at x = 20, 25, 30 at t = 0,
        // 0.5, 1; the parked cars at x = 24 and x = 31, always.
        let ego = |t: f64| 8.0 * t;
        let ego_frame =
            |t: f64, global_x: f64, y: f64, score: f64| car(global_x - ego(t), y, score);
        let frames: Vec<FrameDetections> = [0.0, 0.5, 1.0]
            .into_iter()
            .map(|t| {
                frame(
                    t,
                    ego(t),
                    vec![
                        ego_frame(t, 20.0 + 10.0 * t, 0.0, 0.8),
                        ego_frame(t, 24.0, 3.0, 0.7),
                        ego_frame(t, 31.0, 3.0, 0.6),
                    ],
                )
            })
            .collect();
        let tracks = track_agents(&frames[2], &[&frames[1], &frames[0]], &RULE);
        assert_eq!(tracks.len(), 3);
        let v = tracks[0].velocity().expect("tracked");
        assert!((v[0] - 10.0).abs() < 1e-9 && v[1].abs() < 1e-9, "{v:?}");
        assert_eq!(tracks[0].seconds_before, vec![0.0, 0.5, 1.0]);
        for parked in &tracks[1..] {
            let v = parked.velocity().expect("tracked");
            assert!(v[0].abs() < 1e-9 && v[1].abs() < 1e-9, "{v:?}");
            assert_eq!(parked.positions.len(), 3);
        }
    }

    #[test]
    fn the_second_link_follows_the_first_links_velocity() {
        // One car at 10 m/s along +x, the ego standing. At t = 0 another car stands 1.1 m
        // from where the first was at 0.5 s, far nearer than the first car itself (5 m back):
        // the nearest to where 10 m/s puts the car at t = 0 is the first car.
        let frames = [
            frame(0.0, 0.0, vec![car(0.0, 0.0, 0.9), car(4.0, 0.5, 0.9)]),
            frame(0.5, 0.0, vec![car(5.0, 0.0, 0.9)]),
            frame(1.0, 0.0, vec![car(10.0, 0.0, 0.9)]),
        ];
        let tracks = track_agents(&frames[2], &[&frames[1], &frames[0]], &RULE);
        assert_eq!(
            tracks[0].positions,
            vec![[10.0, 0.0], [5.0, 0.0], [0.0, 0.0]]
        );
        // The first of frame 0's cars, not the nearer standing one (index 1).
        assert_eq!(tracks[0].agents, vec![0, 0, 0]);
        let v = tracks[0].velocity().expect("tracked");
        assert!((v[0] - 10.0).abs() < 1e-9);
    }

    #[test]
    fn unsure_far_other_class_and_other_scene_detections_are_not_linked() {
        let mut pedestrian = car(9.0, 0.0, 0.9);
        pedestrian.detection_name = "pedestrian".into();
        let before = frame(
            0.5,
            0.0,
            vec![
                // Too unsure; another class; 15 m in 0.5 s (30 m/s, past the speed bound).
                car(9.5, 0.0, 0.1),
                pedestrian,
                car(-5.0, 0.0, 0.9),
            ],
        );
        let now = frame(1.0, 0.0, vec![car(10.0, 0.0, 0.9), car(50.0, 0.0, 0.2)]);
        let tracks = track_agents(&now, &[&before], &RULE);
        assert!(tracks.iter().all(|t| t.positions.len() == 1));
        assert!(tracks.iter().all(|t| t.velocity().is_none()));
        // A frame of another scene, or one that is not earlier, ends the tracks.
        let mut other_scene = frame(0.5, 0.0, vec![car(9.0, 0.0, 0.9)]);
        other_scene.meta.scene_name = "b".into();
        let later = frame(1.5, 0.0, vec![car(9.0, 0.0, 0.9)]);
        let close = frame(0.5, 0.0, vec![car(9.0, 0.0, 0.9)]);
        for first in [&other_scene, &later] {
            let tracks = track_agents(&now, &[first, &close], &RULE);
            assert_eq!(tracks[0].positions.len(), 1);
        }
        // And the same frame in order links: 2 m/s.
        let tracks = track_agents(&now, &[&close], &RULE);
        let v = tracks[0].velocity().expect("tracked");
        assert!((v[0] - 2.0).abs() < 1e-9);
    }

    #[test]
    fn the_velocity_is_the_least_squares_slope() {
        // Positions 0, 4, 10 m at −1, −0.5, 0 s: slope = Σ(t−t̄)(x−x̄)/Σ(t−t̄)² with t̄ = −0.5,
        // x̄ = 14/3: ((−0.5)(−14/3) + 0 + (0.5)(16/3)) / 0.5 = (7/3 + 8/3) / 0.5 = 10.
        let track = AgentTrack {
            positions: vec![[10.0, 1.0], [4.0, 1.0], [0.0, 1.0]],
            seconds_before: vec![0.0, 0.5, 1.0],
            agents: vec![0, 0, 0],
        };
        let v = track.velocity().expect("three points");
        assert!((v[0] - 10.0).abs() < 1e-12 && v[1].abs() < 1e-12);
        let alone = AgentTrack {
            positions: vec![[1.0, 1.0]],
            seconds_before: vec![0.0],
            agents: vec![0],
        };
        assert_eq!(alone.velocity(), None);
    }
}
