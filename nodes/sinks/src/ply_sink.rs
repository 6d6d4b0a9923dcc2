//! `ply_sink`: writes each point cloud as `<out>/<frame:06>/<name>.ply` with `x y z intensity`.

use std::path::PathBuf;

use bevworld_graph::io::FolderClaim;
use bevworld_graph::{Inputs, KindSpec, Node, NodeError, ParamError, Port, Registry, Sink};
use bevworld_types::PointCloud;
use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::ply::{PlyEncoding, PlyPoint, encode_ply};
use crate::writes::Writes;

// The node's ports, each named once (`bevworld_graph::Port`).
const CLOUD: Port<PointCloud> = Port::new("cloud");

/// Which coordinates the points are written in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CloudFrame {
    /// As measured, in the LiDAR frame.
    #[default]
    Sensor,
    /// Moved into the ego frame with `ego_from_lidar`.
    Ego,
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct PlySinkParams {
    pub out: PathBuf,
    /// File name without extension.
    #[serde(default = "default_name")]
    pub name: String,
    #[serde(default)]
    pub encoding: PlyEncoding,
    #[serde(default)]
    pub frame: CloudFrame,
}

fn default_name() -> String {
    "LIDAR_TOP".into()
}

pub struct PlySink {
    params: PlySinkParams,
    writes: Writes,
    /// The output folder, held for this run (`FolderClaim`).
    _claim: Option<FolderClaim>,
}

impl Sink for PlySink {
    fn start(&mut self) -> Result<(), NodeError> {
        self._claim = Some(FolderClaim::acquire(&self.params.out).map_err(NodeError::fatal)?);
        Ok(())
    }

    fn consume(&mut self, inputs: &Inputs) -> Result<(), NodeError> {
        let cloud = inputs.get(&CLOUD)?;
        let frame = inputs.header().map(|h| h.seq).unwrap_or(0);
        let points: Vec<PlyPoint> = match self.params.frame {
            CloudFrame::Sensor => cloud
                .points
                .iter()
                .map(|p| PlyPoint::new(p.x, p.y, p.z, p.intensity))
                .collect(),
            CloudFrame::Ego => cloud
                .points
                .iter()
                .map(|p| {
                    let q = cloud.ego_from_lidar.transform_point3(DVec3::new(
                        p.x.into(),
                        p.y.into(),
                        p.z.into(),
                    ));
                    PlyPoint::new(q.x as f32, q.y as f32, q.z as f32, p.intensity)
                })
                .collect(),
        };
        let comment = format!(
            "bevworld {} frame; source {}; timestamp_us {}",
            match self.params.frame {
                CloudFrame::Sensor => "sensor",
                CloudFrame::Ego => "ego",
            },
            cloud.source_file,
            cloud.timestamp_us
        );
        let bytes = encode_ply(&points, self.params.encoding, Some(&comment))
            .map_err(|error| NodeError::item(error.to_string()))?;
        let path = self
            .params
            .out
            .join(format!("{frame:06}"))
            .join(format!("{}.ply", self.params.name));
        self.writes.write(path, bytes)
    }

    fn finish(&mut self) -> Result<(), NodeError> {
        self.writes.flush()
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_checked(
        KindSpec::sink(
            "ply_sink",
            "writes point clouds as PLY (x y z intensity), binary little-endian or ASCII",
        )
        .input(CLOUD.spec()),
        |params: &PlySinkParams| {
            if params.out.as_os_str().is_empty() {
                return Err(ParamError::field("out", "is empty").with_accepted("an output folder"));
            }
            if params.name.is_empty()
                || bevworld_graph::io::safe_file_name(&params.name) != params.name
            {
                return Err(ParamError::field(
                    "name",
                    format!("'{}' is not a file name", params.name),
                )
                .with_accepted("letters, digits, '.', '_', '+' and '-'"));
            }
            Ok(())
        },
        |params: PlySinkParams| {
            Ok(Node::Sink(Box::new(PlySink {
                writes: Writes::new(params.out.clone(), 8),
                params,
                _claim: None,
            })))
        },
    );
}
