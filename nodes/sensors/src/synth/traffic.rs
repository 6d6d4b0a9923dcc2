//! Everything that moves: lane paths through the road grid, other vehicles following them,
//! and the ego, driven by scripted manoeuvres through a kinematic bicycle model.

use glam::{DVec2, DVec3};
use serde::{Deserialize, Serialize};

use super::rng::Rng;
use super::world::{RoadSpec, VehicleBody, vehicle_colour};

/// A piece of a lane path.
#[derive(Clone, Copy, Debug)]
pub enum Segment {
    Line {
        start: DVec2,
        direction: DVec2,
        length: f64,
    },
    /// Counter-clockwise for positive `sweep`.
    Arc {
        center: DVec2,
        radius: f64,
        start_angle: f64,
        sweep: f64,
    },
}

impl Segment {
    pub fn length(&self) -> f64 {
        match *self {
            Segment::Line { length, .. } => length,
            Segment::Arc { radius, sweep, .. } => radius * sweep.abs(),
        }
    }

    /// Position and heading at arc length `s` from the start.
    pub fn pose(&self, s: f64) -> (DVec2, f64) {
        match *self {
            Segment::Line {
                start, direction, ..
            } => (start + direction * s, direction.y.atan2(direction.x)),
            Segment::Arc {
                center,
                radius,
                start_angle,
                sweep,
            } => {
                let angle = start_angle + sweep.signum() * s / radius;
                let position = center + DVec2::new(angle.cos(), angle.sin()) * radius;
                (
                    position,
                    angle + sweep.signum() * std::f64::consts::FRAC_PI_2,
                )
            }
        }
    }

    pub fn curvature(&self) -> f64 {
        match *self {
            Segment::Line { .. } => 0.0,
            Segment::Arc { radius, sweep, .. } => sweep.signum() / radius,
        }
    }
}

/// A chain of segments with arc-length lookup.
#[derive(Clone, Debug, Default)]
pub struct Path {
    pub segments: Vec<Segment>,
    starts: Vec<f64>,
    total: f64,
}

impl Path {
    pub fn push(&mut self, segment: Segment) {
        if segment.length() <= 1e-9 {
            return;
        }
        self.starts.push(self.total);
        self.total += segment.length();
        self.segments.push(segment);
    }

    pub fn length(&self) -> f64 {
        self.total
    }

    fn locate(&self, s: f64) -> Option<(usize, f64)> {
        if self.segments.is_empty() {
            return None;
        }
        let s = s.clamp(0.0, self.total);
        let index = match self.starts.binary_search_by(|start| start.total_cmp(&s)) {
            Ok(i) => i,
            Err(i) => i.saturating_sub(1),
        };
        Some((index, s - self.starts[index]))
    }

    /// Position and heading at arc length `s` (clamped; extrapolated straight past the end).
    pub fn pose(&self, s: f64) -> (DVec2, f64) {
        if s > self.total {
            let (end, heading) = self.pose(self.total);
            return (
                end + DVec2::new(heading.cos(), heading.sin()) * (s - self.total),
                heading,
            );
        }
        match self.locate(s) {
            Some((index, local)) => self.segments[index].pose(local),
            None => (DVec2::ZERO, 0.0),
        }
    }

    pub fn curvature(&self, s: f64) -> f64 {
        self.locate(s)
            .map(|(index, _)| self.segments[index].curvature())
            .unwrap_or(0.0)
    }
}

/// What to do at the next intersection.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Turn {
    Straight,
    Left,
    Right,
}

fn right_of(h: DVec2) -> DVec2 {
    DVec2::new(h.y, -h.x)
}

/// Builds a lane path from a lane position through a sequence of intersections.
///
/// Starts at `start` (intersection indices) heading `heading` (a unit axis vector), `offset` m
/// past the intersection centre, and follows `turns`, one per intersection. A turn that would
/// leave the grid is replaced by one that stays inside.
pub fn plan_route(
    roads: &RoadSpec,
    start: (i64, i64),
    heading: DVec2,
    offset: f64,
    turns: &[Turn],
) -> (Path, Vec<Turn>) {
    let half_lane = roads.lane_width * 0.5;
    let mut path = Path::default();
    let mut node = start;
    let mut h = heading;
    let mut position = roads.intersection(node.0, node.1) + right_of(h) * half_lane + h * offset;
    let mut taken = Vec::new();
    let inside = |n: (i64, i64)| n.0 >= 0 && n.1 >= 0 && n.0 < roads.count && n.1 < roads.count;
    let step = |n: (i64, i64), h: DVec2| (n.0 + h.x.round() as i64, n.1 + h.y.round() as i64);
    for &wanted in turns {
        let next = step(node, h);
        if !inside(next) {
            break;
        }
        let center = roads.intersection(next.0, next.1);
        // Prefer the wanted turn; otherwise any turn whose next intersection exists.
        let options = [wanted, Turn::Straight, Turn::Right, Turn::Left];
        let turn = options
            .into_iter()
            .find(|t| {
                let h2 = match t {
                    Turn::Straight => h,
                    Turn::Right => right_of(h),
                    Turn::Left => -right_of(h),
                };
                inside(step(next, h2))
            })
            .unwrap_or(Turn::Straight);
        match turn {
            Turn::Straight => {
                let through = center + right_of(h) * half_lane;
                push_line(&mut path, position, through);
                position = through;
            }
            Turn::Right => {
                let radius = 4.0;
                let c = center + right_of(h) * (half_lane + radius) - h * (half_lane + radius);
                let entry = c - right_of(h) * radius;
                turn_arc(
                    &mut path,
                    position,
                    entry,
                    (c, radius),
                    -std::f64::consts::FRAC_PI_2,
                );
                h = right_of(h);
                position = center + right_of(h) * half_lane + h * (half_lane + radius);
            }
            Turn::Left => {
                let radius = half_lane + roads.half_width;
                let c = center + (right_of(h) + h) * (half_lane - radius);
                let entry = c + right_of(h) * radius;
                turn_arc(
                    &mut path,
                    position,
                    entry,
                    (c, radius),
                    std::f64::consts::FRAC_PI_2,
                );
                h = -right_of(h);
                position = center + right_of(h) * half_lane + h * (radius - half_lane);
            }
        }
        taken.push(turn);
        node = next;
    }
    // Run on to the next intersection so the path never ends abruptly.
    let next = step(node, h);
    let end = roads.intersection(next.0, next.1) + right_of(h) * half_lane - h * roads.half_width;
    push_line(&mut path, position, end);
    (path, taken)
}

fn push_line(path: &mut Path, from: DVec2, to: DVec2) {
    let delta = to - from;
    let length = delta.length();
    if length > 1e-9 {
        path.push(Segment::Line {
            start: from,
            direction: delta / length,
            length,
        });
    }
}

/// A straight run from `from` to `entry`, then an arc of `radius` about `center` through
/// `sweep` radians (negative: clockwise, a right turn).
fn turn_arc(
    path: &mut Path,
    from: DVec2,
    entry: DVec2,
    (center, radius): (DVec2, f64),
    sweep: f64,
) {
    push_line(path, from, entry);
    let start_vec = entry - center;
    path.push(Segment::Arc {
        center,
        radius,
        start_angle: start_vec.y.atan2(start_vec.x),
        sweep,
    });
}

/// Another vehicle: a body following a path with a varying speed.
#[derive(Clone, Debug)]
pub struct Agent {
    pub body: VehicleBody,
    pub path: Path,
    /// Arc length at 20 Hz from t = 0.
    progress: Vec<f64>,
}

const PROGRESS_HZ: f64 = 20.0;

impl Agent {
    pub fn new(rng: &mut Rng, body: VehicleBody, path: Path, seconds: f64) -> Self {
        let cruise = rng.range(5.0, 11.0);
        let wobble = rng.range(0.1, 0.35);
        let phase = rng.range(0.0, std::f64::consts::TAU);
        let period = rng.range(4.0, 9.0);
        let mut s = 0.0;
        let mut v = cruise * 0.5;
        let mut progress = Vec::new();
        let dt = 1.0 / PROGRESS_HZ;
        let steps = (seconds * PROGRESS_HZ).ceil() as usize + 2;
        for k in 0..steps {
            progress.push(s);
            let t = k as f64 * dt;
            let mut target =
                cruise * (1.0 + wobble * (std::f64::consts::TAU * t / period + phase).sin());
            // Slow for the curve ahead.
            let curve_ahead = (0..4).any(|i| path.curvature(s + 3.0 * i as f64).abs() > 1e-6);
            if curve_ahead {
                target = target.min(4.5);
            }
            let accel = ((target - v) * 0.8).clamp(-3.0, 2.0);
            // Sub-steps keep the integration smooth.
            for _ in 0..5 {
                v = (v + accel * dt / 5.0).max(0.0);
                s += v * dt / 5.0;
            }
        }
        Self {
            body,
            path,
            progress,
        }
    }

    /// The body placed at time `t` (seconds from the scene start).
    pub fn body_at(&self, t: f64) -> VehicleBody {
        let x = (t * PROGRESS_HZ).max(0.0);
        let i = (x.floor() as usize).min(self.progress.len().saturating_sub(2));
        let f = (x - i as f64).clamp(0.0, 1.0);
        let s = self.progress[i] + (self.progress[i + 1] - self.progress[i]) * f;
        let (center, yaw) = self.path.pose(s);
        VehicleBody {
            center,
            yaw,
            ..self.body
        }
    }
}

/// The ego's recorded controls for one frame interval.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EgoControl {
    pub timestamp: i64,
    /// Ego speed at this tick, m/s (the state the controls act on).
    pub speed: f64,
    /// Longitudinal acceleration, m/s^2, held for the interval.
    pub acceleration: f64,
    /// Front-wheel steering angle, rad, held for the interval.
    pub steering: f64,
    /// The scripted manoeuvre being driven.
    pub manoeuvre: String,
}

/// Kinematic bicycle state at the rear axle (the nuScenes ego origin).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BicycleState {
    pub position: DVec2,
    pub yaw: f64,
    pub speed: f64,
}

pub const WHEELBASE: f64 = 2.7;
pub const SUBSTEPS: usize = 10;

impl BicycleState {
    /// Integrates constant controls over `dt` with fixed Euler sub-steps. The same function
    /// replays recorded controls, so actions determine the ego's future exactly.
    pub fn advance(self, acceleration: f64, steering: f64, dt: f64) -> Self {
        let mut state = self;
        let h = dt / SUBSTEPS as f64;
        for _ in 0..SUBSTEPS {
            let (s, c) = state.yaw.sin_cos();
            state.position += DVec2::new(c, s) * state.speed * h;
            state.yaw += state.speed / WHEELBASE * steering.tan() * h;
            state.speed = (state.speed + acceleration * h).max(0.0);
        }
        state
    }
}

/// A speed command: from `from_s` seconds on, aim for `speed`.
#[derive(Clone, Copy, Debug)]
pub struct SpeedPhase {
    pub from_s: f64,
    pub speed: f64,
    pub label: &'static str,
}

/// The ego's script for one scene.
#[derive(Clone, Debug)]
pub struct EgoScript {
    pub path: Path,
    pub turns: Vec<Turn>,
    pub phases: Vec<SpeedPhase>,
    pub initial_speed: f64,
}

impl EgoScript {
    pub fn generate(rng: &mut Rng, roads: &RoadSpec, seconds: f64) -> Self {
        let middle = roads.count / 2;
        let start = (
            middle + rng.below(3) as i64 - 1,
            middle + rng.below(3) as i64 - 1,
        );
        let headings = [DVec2::X, DVec2::Y, -DVec2::X, -DVec2::Y];
        let heading = headings[rng.below(4) as usize];
        let wanted: Vec<Turn> = (0..6)
            .map(|_| match rng.below(5) {
                0 | 1 => Turn::Straight,
                2 | 3 => Turn::Left,
                _ => Turn::Right,
            })
            .collect();
        let (path, turns) = plan_route(roads, start, heading, roads.half_width + 2.0, &wanted);
        // Accelerate, cruise, brake, accelerate again: the speeds a driver would pick in town.
        let cruise = rng.range(7.0, 11.0);
        let mut phases = vec![SpeedPhase {
            from_s: 0.0,
            speed: cruise,
            label: "accelerate",
        }];
        let mut t = rng.range(2.5, 4.0);
        while t < seconds {
            let (speed, label) = match rng.below(3) {
                0 => (rng.range(1.5, 4.0), "brake"),
                1 => (cruise, "keep_speed"),
                _ => (rng.range(cruise, cruise + 3.0), "accelerate"),
            };
            phases.push(SpeedPhase {
                from_s: t,
                speed,
                label,
            });
            t += rng.range(2.0, 4.0);
        }
        Self {
            path,
            turns,
            phases,
            initial_speed: rng.range(2.0, 5.0),
        }
    }

    fn phase_at(&self, t: f64) -> SpeedPhase {
        self.phases
            .iter()
            .rev()
            .find(|p| p.from_s <= t)
            .copied()
            .unwrap_or(SpeedPhase {
                from_s: 0.0,
                speed: 0.0,
                label: "stop",
            })
    }

    /// Drives the script at `rate_hz` for `frames` frames: the states at each frame, and the
    /// controls applied between consecutive frames.
    pub fn drive(
        &self,
        frames: usize,
        rate_hz: f64,
        t0_us: i64,
    ) -> (Vec<BicycleState>, Vec<EgoControl>) {
        let dt = 1.0 / rate_hz;
        let (position, yaw) = self.path.pose(0.0);
        let mut state = BicycleState {
            position,
            yaw,
            speed: self.initial_speed,
        };
        let mut progress: f64 = 0.0;
        let mut states = Vec::with_capacity(frames);
        let mut controls = Vec::with_capacity(frames);
        for k in 0..frames {
            states.push(state);
            let t = k as f64 * dt;
            // Progress: nearest path point near the previous one.
            let mut best = (f64::INFINITY, progress);
            let mut s = (progress - 2.0).max(0.0);
            while s < progress + 8.0 {
                let d = (self.path.pose(s).0 - state.position).length_squared();
                if d < best.0 {
                    best = (d, s);
                }
                s += 0.1;
            }
            progress = best.1;
            // Pure pursuit on the lane path.
            let lookahead = 4.0 + 0.6 * state.speed;
            let (target, _) = self.path.pose(progress + lookahead);
            let to_target = target - state.position;
            let alpha = to_target.y.atan2(to_target.x) - state.yaw;
            let steering = (2.0 * WHEELBASE * alpha.sin() / lookahead)
                .atan()
                .clamp(-0.6, 0.6);
            // Speed: the phase's target, slower in curves.
            let phase = self.phase_at(t);
            let curve_ahead =
                (0..5).any(|i| self.path.curvature(progress + 2.5 * i as f64).abs() > 1e-6);
            let target_speed = if curve_ahead {
                phase.speed.min(5.0)
            } else {
                phase.speed
            };
            let acceleration = ((target_speed - state.speed) * 1.2).clamp(-4.0, 2.5);
            let manoeuvre = if curve_ahead {
                match self.path.curvature(progress + 5.0).partial_cmp(&0.0) {
                    Some(std::cmp::Ordering::Greater) => "turn_left",
                    Some(std::cmp::Ordering::Less) => "turn_right",
                    _ => "keep_lane",
                }
            } else {
                phase.label
            };
            controls.push(EgoControl {
                timestamp: t0_us + (t * 1e6).round() as i64,
                speed: state.speed,
                acceleration,
                steering,
                manoeuvre: manoeuvre.to_string(),
            });
            state = state.advance(acceleration, steering, dt);
        }
        (states, controls)
    }
}

/// Moving vehicles near the ego's start, each on its own random route.
pub fn spawn_agents(
    rng: &mut Rng,
    roads: &RoadSpec,
    around: (i64, i64),
    count: usize,
    seconds: f64,
) -> Vec<Agent> {
    let headings = [DVec2::X, DVec2::Y, -DVec2::X, -DVec2::Y];
    (0..count)
        .map(|_| {
            let start = (
                (around.0 + rng.below(5) as i64 - 2).clamp(0, roads.count - 2),
                (around.1 + rng.below(5) as i64 - 2).clamp(0, roads.count - 2),
            );
            let heading = headings[rng.below(4) as usize];
            let offset = rng.range(
                roads.half_width + 3.0,
                roads.pitch - roads.half_width - 10.0,
            );
            let turns: Vec<Turn> = (0..6)
                .map(|_| [Turn::Straight, Turn::Left, Turn::Right][rng.below(3) as usize])
                .collect();
            let (path, _) = plan_route(roads, start, heading, offset, &turns);
            let body = VehicleBody {
                center: DVec2::ZERO,
                yaw: 0.0,
                size: DVec3::new(
                    rng.range(1.75, 2.0),
                    rng.range(4.2, 5.0),
                    rng.range(1.45, 1.8),
                ),
                colour: vehicle_colour(rng),
            };
            Agent::new(rng, body, path, seconds)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turns_are_continuous_and_end_in_the_right_lane() {
        let roads = RoadSpec::default();
        for turn in [Turn::Left, Turn::Right, Turn::Straight] {
            let (path, taken) = plan_route(&roads, (3, 3), DVec2::X, 10.0, &[turn]);
            assert_eq!(taken, vec![turn]);
            // No jumps between consecutive samples.
            let mut previous = path.pose(0.0).0;
            let mut s = 0.1;
            while s < path.length() {
                let (p, _) = path.pose(s);
                assert!(
                    (p - previous).length() < 0.1 + 1e-6,
                    "jump at s={s} for {turn:?}"
                );
                previous = p;
                s += 0.1;
            }
            let (end, heading) = path.pose(path.length());
            let half_lane = roads.lane_width / 2.0;
            match turn {
                // Keep right: heading north the lane is east of the centre line (x = 4B + L/2),
                // heading south it is west of it.
                Turn::Left => {
                    assert!((heading - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
                    assert!((end.x - (4.0 * roads.pitch + half_lane)).abs() < 1e-9);
                }
                Turn::Right => {
                    assert!((heading + std::f64::consts::FRAC_PI_2).abs() < 1e-9);
                    assert!((end.x - (4.0 * roads.pitch - half_lane)).abs() < 1e-9);
                }
                Turn::Straight => assert!((end.y - (3.0 * roads.pitch - half_lane)).abs() < 1e-9),
            }
        }
    }

    #[test]
    fn routes_never_leave_the_grid() {
        let roads = RoadSpec::default();
        // Heading +x towards the east edge: straight on would leave the grid at (9, 7).
        let (path, taken) = plan_route(
            &roads,
            (7, 7),
            DVec2::X,
            10.0,
            &[Turn::Straight, Turn::Left, Turn::Left],
        );
        assert_ne!(taken[0], Turn::Straight);
        let (lo, hi) = roads.extent();
        let mut s = 0.0;
        while s < path.length() {
            let p = path.pose(s).0;
            assert!(
                p.x > lo.x && p.y > lo.y && p.x < hi.x && p.y < hi.y,
                "{p} at s={s}"
            );
            s += 1.0;
        }
    }

    #[test]
    fn bicycle_model_drives_a_circle_of_the_right_radius() {
        let steering: f64 = 0.2;
        let radius = WHEELBASE / steering.tan();
        let mut state = BicycleState {
            position: DVec2::ZERO,
            yaw: 0.0,
            speed: 5.0,
        };
        let quarter = std::f64::consts::FRAC_PI_2 * radius / 5.0;
        let steps = 200;
        for _ in 0..steps {
            state = state.advance(0.0, steering, quarter / steps as f64);
        }
        assert!((state.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-9);
        assert!(
            (state.position - DVec2::new(radius, radius)).length() < 0.01 * radius,
            "{:?} r={radius}",
            state.position
        );
    }
}
