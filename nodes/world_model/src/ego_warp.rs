//! Moving a BEV latent by the ego's own motion: the current latent resampled into a future ego
//! frame, as if the world stood still. It is the ego-warp baseline, and, with
//! `residual_over_ego_warp`, what the network's prediction is added to, so that the static
//! world is moved rather than re-predicted. The warp itself is the shared one
//! (`bevworld_types::bev_warp`); what is the world model's is how much of it a frame's base
//! takes.

pub use bevworld_types::bev_warp::{LatentGrid, PlanarMotion, warp_latent};

/// What a residual model's future frames are the residual over: the ego-warped current
/// latent, weighted by the horizon (`WorldModelConfig::ego_warp_fade_s`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EgoWarpBase {
    /// Diffuse `x − w·warp` (true) or the latent itself (false, `w = 0`).
    pub residual: bool,
    /// `w` falls linearly from 1 now to 0 at this horizon; `None`: 1 at every horizon.
    pub fade_s: Option<f64>,
}

impl EgoWarpBase {
    /// The warp's weight `w` in the base of a frame `horizon_s` seconds ahead.
    pub fn weight(&self, horizon_s: f64) -> f32 {
        match (self.residual, self.fade_s) {
            (false, _) => 0.0,
            (true, None) => 1.0,
            (true, Some(fade)) => linear_fade(horizon_s, fade) as f32,
        }
    }
}

/// `1 − h / h_fade`, clamped to [0, 1]: 1 now, 0 from `fade_s` on. How the warp's weight in
/// the base and the residual shrink's threshold fall with the horizon.
pub fn linear_fade(horizon_s: f64, fade_s: f64) -> f64 {
    (1.0 - horizon_s / fade_s).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_warp_fades_linearly_to_zero_at_its_horizon_and_stays_there() {
        let fade = EgoWarpBase {
            residual: true,
            fade_s: Some(4.0),
        };
        for (horizon, weight) in [
            (0.0, 1.0),
            (0.5, 0.875),
            (1.0, 0.75),
            (3.0, 0.25),
            (4.0, 0.0),
            (6.0, 0.0),
        ] {
            assert!((fade.weight(horizon) - weight).abs() < 1e-6, "{horizon} s");
        }
        let full = EgoWarpBase {
            residual: true,
            fade_s: None,
        };
        assert_eq!(full.weight(3.0), 1.0);
        let latent = EgoWarpBase {
            residual: false,
            fade_s: None,
        };
        assert_eq!(latent.weight(0.5), 0.0);
    }
}
