//! One synthetic scene: the city, the traffic and the ego's drive, queryable at any time.

use glam::{DQuat, DVec2, DVec3};

use bevworld_types::{Manoeuvre, Pose};

use super::people::{Person, person_solids, spawn_cyclists, spawn_pedestrians};
use super::render::Snapshot;
use super::rng::Rng;
use super::traffic::{Agent, BicycleState, EgoControl, EgoScript, WHEELBASE, spawn_agents};
use super::world::{City, RoadSpec, Solid, VehicleBody};

/// Sensor ticks per second (all sensors), and keyframes every this many ticks (2 Hz).
pub const RATE_HZ: f64 = 12.0;
pub const KEYFRAME_EVERY: usize = 6;
pub const TICK_US: i64 = 83_333;

pub struct SceneWorld {
    pub seed: u64,
    pub city: City,
    pub agents: Vec<Agent>,
    /// Pedestrians, then cyclists (`with_people`); none by default.
    pub people: Vec<Person>,
    pub script: EgoScript,
    /// Ego state at each tick.
    pub states: Vec<BicycleState>,
    /// Controls held from each tick to the next.
    pub controls: Vec<EgoControl>,
    pub t0_us: i64,
    pub ticks: usize,
}

impl SceneWorld {
    pub fn new(seed: u64, seconds: f64, agent_count: usize) -> Self {
        let roads = RoadSpec::default();
        let city = City::generate(seed, roads);
        let mut rng = Rng::fork(seed, 2);
        let script = EgoScript::generate(&mut rng, &roads, seconds);
        let start = script.path.pose(0.0).0;
        let around = (
            (start.x / roads.pitch).round() as i64,
            (start.y / roads.pitch).round() as i64,
        );
        let mut agent_rng = Rng::fork(seed, 3);
        let agents = spawn_agents(&mut agent_rng, &roads, around, agent_count, seconds + 1.0);
        let ticks = ((seconds * RATE_HZ).round() as usize).max(1);
        // A fixed epoch per seed keeps timestamps realistic and distinct between scenes.
        let t0_us = 1_700_000_000_000_000 + (seed % 1_000_000) as i64 * 1_000_000;
        let (states, controls) = script.drive(ticks, RATE_HZ, t0_us);
        Self {
            seed,
            city,
            agents,
            people: Vec::new(),
            script,
            states,
            controls,
            t0_us,
            ticks,
        }
    }

    /// The same scene with pedestrians on the sidewalks and cyclists on the roads around the
    /// ego's start, each drawn from a stream of its own: the rest of the scene is unchanged.
    pub fn with_people(mut self, pedestrians: usize, cyclists: usize) -> Self {
        let roads = self.city.roads;
        let start = self.script.path.pose(0.0).0;
        let around = (
            (start.x / roads.pitch).round() as i64,
            (start.y / roads.pitch).round() as i64,
        );
        self.people = spawn_pedestrians(&mut Rng::fork(self.seed, 4), &roads, around, pedestrians);
        self.people.extend(spawn_cyclists(
            &mut Rng::fork(self.seed, 5),
            &roads,
            around,
            cyclists,
        ));
        self
    }

    /// The same scene, but from the tick at `at_s` seconds on the ego drives `manoeuvre`
    /// through the bicycle model, from the speed and steering it had there: `keep` holds the
    /// steering and the speed (a constant yaw rate), `left` and `right` steer for the
    /// manoeuvre's yaw rate at the current speed, `faster`, `slower` and `stop` go straight at
    /// their acceleration (never below standstill). Everything before the branch, and the
    /// world and its traffic, stay as they were.
    pub fn branched(mut self, at_s: f64, manoeuvre: Manoeuvre) -> Self {
        let start = ((at_s * RATE_HZ).round() as usize).min(self.ticks);
        let held_steering = start
            .checked_sub(1)
            .and_then(|k| self.controls.get(k))
            .map_or(0.0, |c| c.steering);
        let dt = 1.0 / RATE_HZ;
        for k in start..self.ticks {
            let state = self.states[k];
            let steering = match manoeuvre {
                Manoeuvre::Keep => held_steering,
                Manoeuvre::Left | Manoeuvre::Right => {
                    let yaw_rate = manoeuvre.yaw_rate(0.0);
                    (yaw_rate * WHEELBASE / state.speed.max(0.5))
                        .atan()
                        .clamp(-0.6, 0.6)
                }
                Manoeuvre::Faster | Manoeuvre::Slower | Manoeuvre::Stop => 0.0,
            };
            let acceleration = manoeuvre.acceleration();
            self.controls[k] = EgoControl {
                timestamp: self.controls[k].timestamp,
                speed: state.speed,
                acceleration,
                steering,
                manoeuvre: format!("branch_{}", manoeuvre.name()),
            };
            if k + 1 < self.ticks {
                self.states[k + 1] = state.advance(acceleration, steering, dt);
            }
        }
        self
    }

    pub fn tick_time_us(&self, tick: usize) -> i64 {
        self.t0_us + tick as i64 * TICK_US
    }

    /// The ego's state at any time: the nearest earlier tick advanced with its held controls.
    pub fn ego_state(&self, t_us: i64) -> BicycleState {
        let k = ((t_us - self.t0_us).div_euclid(TICK_US)).clamp(0, self.ticks as i64 - 1) as usize;
        let tau = (t_us - self.tick_time_us(k)) as f64 * 1e-6;
        if tau == 0.0 {
            return self.states[k];
        }
        let control = &self.controls[k];
        self.states[k].advance(control.acceleration, control.steering, tau)
    }

    pub fn global_from_ego(&self, t_us: i64) -> Pose {
        let state = self.ego_state(t_us);
        Pose::from_rotation_translation(
            DQuat::from_rotation_z(state.yaw),
            DVec3::new(state.position.x, state.position.y, 0.0),
        )
    }

    /// Parked bodies, then moving bodies at `t_us`, with their instance numbers (from 1).
    pub fn vehicles_at(&self, t_us: i64) -> Vec<(u32, VehicleBody, bool)> {
        let t = (t_us - self.t0_us) as f64 * 1e-6;
        let mut vehicles = Vec::new();
        for (i, agent) in self.agents.iter().enumerate() {
            vehicles.push((i as u32 + 1, agent.body_at(t), true));
        }
        let offset = self.agents.len() as u32 + 1;
        for (i, body) in self.city.parked.iter().enumerate() {
            vehicles.push((offset + i as u32, *body, false));
        }
        vehicles
    }

    /// The people at `t_us`, with their instance numbers (after every vehicle's).
    pub fn people_at(&self, t_us: i64) -> Vec<(u32, &Person, VehicleBody)> {
        let t = (t_us - self.t0_us) as f64 * 1e-6;
        let offset = (self.agents.len() + self.city.parked.len()) as u32 + 1;
        self.people
            .iter()
            .enumerate()
            .map(|(i, person)| (offset + i as u32, person, person.body_at(t)))
            .collect()
    }

    /// Everything at one instant, ready to ray cast.
    pub fn snapshot(&self, t_us: i64) -> Snapshot {
        let mut solids: Vec<Solid> = self.city.solids.clone();
        let ego = self.ego_state(t_us).position;
        for (instance, body, _) in self.vehicles_at(t_us) {
            // A moving car overlapping the ego would sit inside its cameras; leave it out.
            if (body.center - ego).length() < 3.0 {
                continue;
            }
            solids.extend(body.solids(instance));
        }
        for (instance, person, body) in self.people_at(t_us) {
            if (body.center - ego).length() < 3.0 {
                continue;
            }
            solids.extend(person_solids(person.kind, &body, instance));
        }
        Snapshot::new(self.city.roads, solids)
    }

    pub fn ego_position(&self, t_us: i64) -> DVec2 {
        self.ego_state(t_us).position
    }
}
