//! Per-channel mean and standard deviation of latents over a dataset: the contract between the
//! tokenizer, which computes them for its weights, and the world model, which diffuses
//! standardised latents `(z - mean) / std`. Neither depends on the other; both read this.
//!
//! The accumulator merges per-latent sums with Chan et al.'s parallel update, in f64, so
//! millions of cells lose no precision and the order of frames does not matter.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LatentStats {
    pub mean: Vec<f64>,
    /// Population standard deviation (over all cells of all latents).
    pub std: Vec<f64>,
    /// Latents the statistics were computed over.
    pub frames: usize,
}

impl LatentStats {
    /// `(z - mean) / std` per channel, for a channel-major `[C, H, W]` latent.
    pub fn standardize(&self, latent: &mut [f32]) {
        self.apply(latent, |v, m, s| ((v as f64 - m) / s) as f32);
    }

    /// The inverse of `standardize`.
    pub fn destandardize(&self, latent: &mut [f32]) {
        self.apply(latent, |v, m, s| (v as f64 * s + m) as f32);
    }

    fn apply(&self, latent: &mut [f32], f: impl Fn(f32, f64, f64) -> f32) {
        let channels = self.mean.len().max(1);
        let per_channel = latent.len() / channels;
        for (c, plane) in latent
            .chunks_mut(per_channel.max(1))
            .enumerate()
            .take(channels)
        {
            let (m, s) = (self.mean[c], self.std[c].max(f64::MIN_POSITIVE));
            for v in plane {
                *v = f(*v, m, s);
            }
        }
    }
}

/// Why a latent could not be added to the statistics.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum LatentStatsError {
    #[error("a latent of {values} values does not split into {channels} channels")]
    Shape { values: usize, channels: usize },
    #[error("latent has {channels} channels, earlier ones had {earlier}")]
    Channels { channels: usize, earlier: usize },
    #[error("latent contains non-finite values")]
    NonFinite,
    #[error("no latents were added")]
    Empty,
    #[error(
        "latent channel {channel} never varies (every value {value}): it cannot be standardised, \
         and a world model would divide by a zero deviation; the latents are degenerate"
    )]
    ZeroVariance { channel: usize, value: f64 },
}

/// Running per-channel count, mean and sum of squared deviations.
#[derive(Clone, Debug, Default)]
pub struct LatentStatsAccumulator {
    count: Vec<f64>,
    mean: Vec<f64>,
    m2: Vec<f64>,
    frames: usize,
}

impl LatentStatsAccumulator {
    /// Adds one channel-major `[C, H, W]` latent with `channels` channels.
    pub fn add(&mut self, latent: &[f32], channels: usize) -> Result<(), LatentStatsError> {
        if channels == 0 || latent.is_empty() || !latent.len().is_multiple_of(channels) {
            return Err(LatentStatsError::Shape {
                values: latent.len(),
                channels,
            });
        }
        if self.mean.is_empty() {
            self.count = vec![0.0; channels];
            self.mean = vec![0.0; channels];
            self.m2 = vec![0.0; channels];
        } else if self.mean.len() != channels {
            return Err(LatentStatsError::Channels {
                channels,
                earlier: self.mean.len(),
            });
        }
        if latent.iter().any(|v| !v.is_finite()) {
            return Err(LatentStatsError::NonFinite);
        }
        let per_channel = latent.len() / channels;
        for (c, plane) in latent.chunks(per_channel).enumerate() {
            let n = per_channel as f64;
            let mean = plane.iter().map(|&v| v as f64).sum::<f64>() / n;
            let m2 = plane
                .iter()
                .map(|&v| (v as f64 - mean).powi(2))
                .sum::<f64>();
            let total = self.count[c] + n;
            let delta = mean - self.mean[c];
            self.mean[c] += delta * n / total;
            self.m2[c] += m2 + delta * delta * self.count[c] * n / total;
            self.count[c] = total;
        }
        self.frames += 1;
        Ok(())
    }

    pub fn finish(&self) -> Result<LatentStats, LatentStatsError> {
        if self.frames == 0 {
            return Err(LatentStatsError::Empty);
        }
        let std: Vec<f64> = self
            .m2
            .iter()
            .zip(&self.count)
            .map(|(m2, n)| (m2 / n).sqrt())
            .collect();
        if let Some(channel) = std.iter().position(|s| !(*s > 0.0)) {
            return Err(LatentStatsError::ZeroVariance {
                channel,
                value: self.mean[channel],
            });
        }
        Ok(LatentStats {
            mean: self.mean.clone(),
            std,
            frames: self.frames,
        })
    }
}

/// The mean absolute difference of two latents, value by value: the standardised latent L1 of
/// the forecast metrics and of the world model's validation when both are standardised. Values
/// beyond the shorter one are not compared.
pub fn mean_abs_difference(a: &[f32], b: &[f32]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| f64::from((x - y).abs()))
        .sum::<f64>()
        / a.len().min(b.len()).max(1) as f64
}
