//! The `pillarize` node: `SensorFrame` in, `Pillars` out, with its drops in the node's metrics.

use bevworld_graph::{
    Figures, Inputs, KindSpec, Node, NodeError, Outputs, ParamError, Port, Registry, Task,
};
use bevworld_types::{FrameMeta, PillarGrid, PillarStats, Pillars, SensorFrame};
use serde::{Deserialize, Serialize};

use crate::{Limits, Pillarizer};

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");
const PILLARS: Port<Pillars> = Port::new("pillars");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PillarizeParams {
    /// Grid over the ego frame; the default is the paper's 384 x 384 over [-80, 80) m.
    #[serde(default)]
    pub grid: PillarGrid,
    #[serde(default = "default_points")]
    pub max_points_per_pillar: usize,
    #[serde(default = "default_pillars")]
    pub max_pillars: usize,
}

fn default_points() -> usize {
    Limits::default().max_points_per_pillar
}

fn default_pillars() -> usize {
    Limits::default().max_pillars
}

pub struct PillarizeNode {
    pillarizer: Pillarizer,
    points: Vec<[f32; 4]>,
    totals: PillarStats,
    frames: u64,
    pillars: u64,
}

impl Task for PillarizeNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let frame = inputs.get(&FRAME)?;
        crate::ego_points_into(&frame.lidar, &mut self.points);
        let mut pillars: Pillars = self.pillarizer.run(&self.points);
        pillars.meta = FrameMeta {
            sample_token: frame.sample_token.clone(),
            frame_token: frame.frame_token.clone(),
            scene_name: frame.scene_name.clone(),
            time_of_validity_us: frame.time_of_validity_us,
            global_from_ego: frame.global_from_ego,
            keyframe: frame.keyframe,
        };
        let s = pillars.stats;
        self.totals.points_in += s.points_in;
        self.totals.points_kept += s.points_kept;
        self.totals.outside_range += s.outside_range;
        self.totals.non_finite += s.non_finite;
        self.totals.dropped_by_pillar_limit += s.dropped_by_pillar_limit;
        self.totals.dropped_pillars += s.dropped_pillars;
        self.totals.points_in_dropped_pillars += s.points_in_dropped_pillars;
        self.frames += 1;
        self.pillars += pillars.len() as u64;
        out.send(&PILLARS, pillars)
    }

    fn report(&self) -> Figures {
        let t = &self.totals;
        let mut figures = Figures::new();
        figures.insert("points_in".into(), t.points_in as f64);
        figures.insert("points_kept".into(), t.points_kept as f64);
        figures.insert("dropped_outside_range".into(), t.outside_range as f64);
        figures.insert("dropped_non_finite".into(), t.non_finite as f64);
        figures.insert(
            "dropped_by_pillar_limit".into(),
            t.dropped_by_pillar_limit as f64,
        );
        figures.insert("dropped_pillars".into(), t.dropped_pillars as f64);
        figures.insert(
            "points_in_dropped_pillars".into(),
            t.points_in_dropped_pillars as f64,
        );
        if self.frames > 0 {
            figures.insert(
                "mean_pillars_per_frame".into(),
                self.pillars as f64 / self.frames as f64,
            );
        }
        figures
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::task("pillarize", "groups a sweep's points (ego frame) into the non-empty PointPillars pillars of a BEV grid")
            .input(FRAME.spec())
            .output(PILLARS.spec()),
        |params: &PillarizeParams| {
            params.grid.validate().map_err(|error| ParamError::field("grid", error.to_string()).with_accepted("finite ranges [min, max) that pillar_size divides"))?;
            if params.max_points_per_pillar == 0 || params.max_points_per_pillar > 4096 {
                return Err(ParamError::field("max_points_per_pillar", format!("{} is out of range", params.max_points_per_pillar)).with_accepted("1..=4096"));
            }
            if params.max_pillars == 0 {
                return Err(ParamError::field("max_pillars", "must be at least 1").with_accepted("an integer >= 1"));
            }
            Ok(())
        },
        |params: PillarizeParams| {
            let limits = Limits { max_points_per_pillar: params.max_points_per_pillar, max_pillars: params.max_pillars };
            Ok(Node::Task(Box::new(PillarizeNode {
                pillarizer: Pillarizer::new(params.grid, limits),
                points: Vec::new(),
                totals: PillarStats::default(),
                frames: 0,
                pillars: 0,
            })))
        },
    );
}
