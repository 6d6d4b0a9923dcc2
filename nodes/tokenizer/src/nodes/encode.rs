//! `encode`: a sensor frame and its pillars in, the 4-channel BEV latent out (and, when
//! something listens, the fused BEV feature before compression).

use std::sync::Arc;

use bevworld_graph::{Inputs, KindSpec, Models, Node, NodeError, Outputs, Port, Registry, Task};
use bevworld_types::{BevFeatures, BevGrid, FrameMeta, Pillars, SensorFrame};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::config::TokenizerConfig;
use crate::frame_input::FrameInputs;
use crate::nodes::loaded_model::{LoadedModel, ModelParams};

// The node's ports, each named once (`bevworld_graph::Port`).
const FRAME: Port<SensorFrame> = Port::new("frame");
const PILLARS: Port<Pillars> = Port::new("pillars");
const FUSED: Port<BevFeatures> = Port::new("fused");
const LATENT: Port<BevFeatures> = Port::new("latent");

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct EncodeParams {
    #[serde(flatten)]
    pub model: ModelParams,
}

pub struct EncodeNode {
    loaded: Arc<LoadedModel>,
    inputs: FrameInputs,
}

/// The grid the latent (and the fused feature) covers.
pub fn latent_grid(config: &TokenizerConfig) -> BevGrid {
    let n = config.latent_size();
    BevGrid {
        x_range: [config.bev.x_range[0] as f32, config.bev.x_range[1] as f32],
        y_range: [config.bev.y_range[0] as f32, config.bev.y_range[1] as f32],
        resolution: ((config.bev.x_range[1] - config.bev.x_range[0]) / n as f64) as f32,
        height: n,
        width: n,
    }
}

impl EncodeNode {
    fn features(
        &self,
        meta: &FrameMeta,
        tensor: Tensor<4>,
        prefix: &str,
    ) -> Result<BevFeatures, NodeError> {
        let [_, channels, _, _] = tensor.dims();
        let data = tensor
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|error| NodeError::item(format!("reading the {prefix} back: {error:?}")))?;
        Ok(BevFeatures {
            meta: meta.clone(),
            grid: latent_grid(&self.loaded.config),
            channels: (0..channels).map(|c| format!("{prefix}_{c}")).collect(),
            data,
            model: self.loaded.config.name.clone(),
            weights_hash: self.loaded.weights_hash.clone(),
        })
    }
}

impl Task for EncodeNode {
    fn process(&mut self, inputs: &Inputs, out: &mut Outputs) -> Result<(), NodeError> {
        let frame = inputs.get(&FRAME)?;
        let pillars = inputs.get(&PILLARS)?;
        if pillars.meta.frame_token != frame.frame_token {
            return Err(NodeError::item(format!(
                "the pillars belong to frame {}, not to frame {}: connect `pillars` to a pillarize node fed by the same source",
                pillars.meta.frame_token, frame.frame_token
            )));
        }
        let input = self
            .inputs
            .encoder_input(frame, pillars, &self.loaded.device)
            .map_err(|error| NodeError::item(error.to_string()))?;
        let encoded = self.loaded.model.encode(input);
        let meta = &pillars.meta;
        if out.is_connected(&FUSED) {
            let fused = self.features(meta, encoded.fused, "fused")?;
            out.send(&FUSED, fused)?;
        }
        let latent = self.features(meta, encoded.latent, "latent")?;
        if latent.data.iter().any(|v| !v.is_finite()) {
            return Err(NodeError::item(format!(
                "frame {}: the latent has non-finite values",
                frame.frame_token
            )));
        }
        out.send(&LATENT, latent)
    }
}

pub fn register(registry: &mut Registry) {
    registry.register_with_models(
        KindSpec::task(
            "encode",
            "the BEV tokenizer's encoder: six cameras and the sweep's pillars to the C' x h x w latent",
        )
        .input(FRAME.spec())
        .input(PILLARS.spec())
        .output(LATENT.spec())
        .output(FUSED.spec()),
        |params: &EncodeParams, models: &Models| params.model.check(models),
        |params: EncodeParams, models: &Models| {
            let loaded = params.model.load_shared(models)?;
            Ok(Node::Task(Box::new(EncodeNode {
                inputs: FrameInputs::new(&loaded.config),
                loaded,
            })))
        },
    );
}
