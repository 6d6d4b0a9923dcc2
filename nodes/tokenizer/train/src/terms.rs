//! The tokenizer's loss terms, each defined once: its metrics column, how a message names it,
//! and its weight in the config. A frame's outcome, a step's report, the step's means, the
//! non-finite check and the metrics log all go through this list, so a new term is one new
//! line here.

use crate::config::LossWeights;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Term {
    /// L1 between rendered and input RGB.
    Rgb,
    /// Mean squared RGB error.
    RgbSquared,
    /// L1 between rendered depth and the LiDAR returns, metres.
    Lidar,
    /// Mip-NeRF 360's distortion of the LiDAR rays' render weights.
    Distortion,
    /// The LiDAR returns' negative log-likelihood under their rays' render weights.
    Termination,
    /// VGG16 features of the rendered cameras against the inputs.
    Perceptual,
    /// The generator's adversarial (hinge) term.
    Gan,
    /// The sparsity prior on the field's opacity at every voxel centre.
    Sparsity,
    /// The patch discriminator's own hinge loss (its own step, not the generator's).
    Discriminator,
}

impl Term {
    /// Every term, in the order a frame's loss sums them.
    pub const ALL: [Term; 9] = [
        Term::Lidar,
        Term::Distortion,
        Term::Termination,
        Term::Rgb,
        Term::RgbSquared,
        Term::Perceptual,
        Term::Gan,
        Term::Sparsity,
        Term::Discriminator,
    ];

    /// The term's column in `metrics.csv`.
    pub const fn column(self) -> &'static str {
        match self {
            Term::Rgb => "loss_rgb",
            Term::RgbSquared => "loss_rgb_squared",
            Term::Lidar => "loss_lidar",
            Term::Distortion => "loss_distortion",
            Term::Termination => "loss_termination",
            Term::Perceptual => "loss_perceptual",
            Term::Gan => "loss_gan",
            Term::Sparsity => "loss_sparsity",
            Term::Discriminator => "loss_discriminator",
        }
    }

    /// How messages name the term.
    pub const fn name(self) -> &'static str {
        match self {
            Term::Rgb => "RGB loss",
            Term::RgbSquared => "squared RGB loss",
            Term::Lidar => "LiDAR loss",
            Term::Distortion => "LiDAR distortion loss",
            Term::Termination => "LiDAR termination loss",
            Term::Perceptual => "perceptual loss",
            Term::Gan => "GAN loss",
            Term::Sparsity => "density sparsity prior",
            Term::Discriminator => "discriminator loss",
        }
    }

    /// The term's weight in the generator's loss (the discriminator's, for its own step).
    pub fn weight(self, weights: &LossWeights) -> f64 {
        match self {
            Term::Rgb => weights.rgb_l1,
            Term::RgbSquared => weights.rgb_l2,
            Term::Lidar => weights.lidar_l1,
            Term::Distortion => weights.lidar_distortion,
            Term::Termination => weights.lidar_termination,
            Term::Perceptual => weights.perceptual,
            Term::Gan => weights.gan_generator,
            Term::Sparsity => weights.density_sparsity,
            Term::Discriminator => weights.gan_discriminator,
        }
    }
}

/// The value of each term a frame or a step took.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TermValues(Vec<(Term, f64)>);

impl TermValues {
    pub fn push(&mut self, term: Term, value: f64) {
        self.0.push((term, value));
    }

    pub fn get(&self, term: Term) -> Option<f64> {
        self.0.iter().find(|(t, _)| *t == term).map(|(_, v)| *v)
    }

    /// The first term whose value is not finite, to name in an error.
    pub fn first_non_finite(&self) -> Option<Term> {
        self.0.iter().find(|(_, v)| !v.is_finite()).map(|(t, _)| *t)
    }

    /// The mean of each term over frames that all took it.
    pub fn mean(frames: &[TermValues]) -> TermValues {
        let count = frames.len().max(1) as f64;
        TermValues(
            Term::ALL
                .iter()
                .filter_map(|&term| {
                    let values: Option<Vec<f64>> = frames.iter().map(|f| f.get(term)).collect();
                    values
                        .filter(|v| !v.is_empty())
                        .map(|v| (term, v.iter().sum::<f64>() / count))
                })
                .collect(),
        )
    }

    /// `(metrics column, value)` pairs, for the step report and the log.
    pub fn columns(&self) -> Vec<(&'static str, f64)> {
        self.0.iter().map(|(t, v)| (t.column(), *v)).collect()
    }
}
