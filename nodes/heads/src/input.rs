//! A detector's input for one frame: its map standardised per channel, and for two frames the
//! previous keyframe's map brought into the current ego frame by the ego motion between them
//! (the shared BEV warp), stacked behind it. What stands still then lies in the same cells in
//! both, and what moves shows its motion.

use bevworld_types::{LatentGrid, PlanarMotion, Pose, warp_latent};

use crate::config::InputSpec;

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InputError {
    #[error(
        "a map of {found} values, but the detector reads {expected} ({channels} x {height} x {width})"
    )]
    Shape {
        found: usize,
        expected: usize,
        channels: usize,
        height: usize,
        width: usize,
    },
    #[error("the map holds {count} non-finite values (NaN or Inf)")]
    NonFinite { count: usize },
}

/// A map and where its ego was.
pub struct PosedMap<'a> {
    /// `[C, H, W]`, as exported.
    pub values: &'a [f32],
    pub global_from_ego: Pose,
}

impl InputSpec {
    /// Values per frame's map.
    pub fn frame_len(&self) -> usize {
        self.channels * self.grid.height * self.grid.width
    }

    fn standardised(&self, values: &[f32]) -> Result<Vec<f32>, InputError> {
        if values.len() != self.frame_len() {
            return Err(InputError::Shape {
                found: values.len(),
                expected: self.frame_len(),
                channels: self.channels,
                height: self.grid.height,
                width: self.grid.width,
            });
        }
        let count = values.iter().filter(|v| !v.is_finite()).count();
        if count > 0 {
            return Err(InputError::NonFinite { count });
        }
        let plane = self.grid.height * self.grid.width;
        Ok(values
            .chunks(plane)
            .zip(self.mean.iter().zip(&self.std))
            .flat_map(|(channel, (mean, std))| channel.iter().map(move |v| (v - mean) / std))
            .collect())
    }

    /// The detector's input `[C·F, H, W]`: `current` standardised, then for two frames
    /// `previous` standardised and warped into `current`'s ego frame; the standardised mean (0)
    /// where the previous map did not reach. Two frames without a previous one (a scene's first
    /// keyframe) read the current map twice: no motion seen.
    pub fn assemble(
        &self,
        current: &PosedMap,
        previous: Option<&PosedMap>,
    ) -> Result<Vec<f32>, InputError> {
        let mut input = self.standardised(current.values)?;
        if self.frames < 2 {
            return Ok(input);
        }
        let behind = match previous {
            Some(previous) => {
                let standardised = self.standardised(previous.values)?;
                let grid = LatentGrid::of(&self.grid, self.channels);
                let previous_from_current =
                    PlanarMotion::between(&previous.global_from_ego, &current.global_from_ego);
                warp_latent(&standardised, &grid, &previous_from_current, 0.0)
            }
            None => input.clone(),
        };
        input.extend(behind);
        Ok(input)
    }
}
