//! `bev_stats`: pillars to a dense BEV map of occupancy and height statistics, the exportable
//! LiDAR feature until the tokenizer's latent takes its place on the same sink.

use bevworld_graph::{Inputs, KindSpec, Node, NodeError, Outputs, Port, Registry, Task};
use bevworld_types::{BevFeatures, BevGrid, PILLAR_FEATURES, Pillars};
use serde::{Deserialize, Serialize};

// The node's ports, each named once (`bevworld_graph::Port`).
const PILLARS: Port<Pillars> = Port::new("pillars");
const FEATURES: Port<BevFeatures> = Port::new("features");

pub const CHANNELS: [&str; 5] = [
    "occupancy",
    "log1p_point_count",
    "z_max_m",
    "z_mean_m",
    "intensity_mean",
];

/// The `[5, H, W]` statistics of a sweep's pillars; empty cells are all zero.
pub fn bev_statistics(pillars: &Pillars) -> BevFeatures {
    let (width, height) = pillars.grid.size();
    let plane = width * height;
    let mut data = vec![0.0f32; CHANNELS.len() * plane];
    for p in 0..pillars.len() {
        let (iy, ix) = (
            pillars.coords[2 * p] as usize,
            pillars.coords[2 * p + 1] as usize,
        );
        let n = pillars.point_counts[p] as usize;
        let (mut z_max, mut z_sum, mut intensity_sum) = (f32::NEG_INFINITY, 0.0f32, 0.0f32);
        for k in 0..n {
            let z = pillars.feature(p, k, 2);
            z_max = z_max.max(z);
            z_sum += z;
            intensity_sum += pillars.feature(p, k, 3);
        }
        let cell = iy * width + ix;
        let values = [
            1.0,
            (n as f32).ln_1p(),
            z_max,
            z_sum / n as f32,
            intensity_sum / n as f32,
        ];
        for (c, value) in values.into_iter().enumerate() {
            data[c * plane + cell] = value;
        }
    }
    debug_assert_eq!(PILLAR_FEATURES, 9);
    BevFeatures {
        meta: pillars.meta.clone(),
        grid: BevGrid {
            x_range: pillars.grid.x_range,
            y_range: pillars.grid.y_range,
            resolution: pillars.grid.pillar_size,
            height,
            width,
        },
        channels: CHANNELS.iter().map(|c| c.to_string()).collect(),
        data,
        model: "pillar_bev_stats".into(),
        weights_hash: "none".into(),
    }
}

#[derive(Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct NoParams {}

struct BevStatsNode;

impl Task for BevStatsNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        out.send(&FEATURES, bev_statistics(inputs.get(&PILLARS)?))
    }
}

pub fn register(registry: &mut Registry) {
    registry.register(
        KindSpec::task("bev_stats", "pillars to a dense [5, H, W] BEV map: occupancy, log1p point count, max and mean height, mean intensity")
            .input(PILLARS.spec())
            .output(FEATURES.spec()),
        |_: NoParams| Ok(Node::Task(Box::new(BevStatsNode))),
    );
}
