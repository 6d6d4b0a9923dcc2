//! A forecast: the N future latents of a context, sampled with DDIM, every future frame
//! denoised together in one network pass per step.

use bevworld_blocks::init::random_values;
use burn::prelude::*;

use crate::config::WorldModelConfig;
use crate::ddim::{DdimConfig, DdimError, clean_and_noise, step, timesteps};
use crate::fine_tokens::FineTokenSelection;
use crate::model::WorldModel;
use crate::schedule::NoiseSchedule;

/// What a forecast starts from, standardised (`LatentStats::standardize`) and normalised
/// (`ActionStats::normalise`).
pub struct ForecastInputs {
    /// The condition frames: P past frames and the current one.
    pub context: Tensor<5>, // [B, P+1, C', H, W]
    /// The action into every frame, condition frames first, then the N future frames.
    pub actions: Tensor<3>, // [B, P+1+N, 5]
    /// The current latent warped into each future ego frame, which the network's residual is
    /// added to (`residual_over_ego_warp`); `None` for a model that predicts the latent itself.
    pub base: Option<Tensor<5>>, // [B, N, C', H, W]
    /// The current latent warped into each future ego frame, all of it: what a model with
    /// `ego_warp_input` embeds.
    pub warped: Tensor<5>, // [B, N, C', H, W]
    /// The coarse tokens a model with `fine_tokens` opens into fine ones, per batch item
    /// (`fine_tokens::select_for_context`); empty for a model without them.
    pub fine_tokens: FineTokenSelection,
}

/// Draws `[B, N, C', H, W]` standard normal noise from `seed`, on the host.
pub fn seeded_noise(seed: u64, shape: [usize; 5], device: &Device) -> Tensor<5> {
    let count = shape.iter().product();
    Tensor::from_data(
        TensorData::new(random_values(seed, count, 0.0, 1.0, true), shape),
        device,
    )
}

/// The noise seed of a forecast's draw `draw` (draw 0 is the sampler's own seed). The draws
/// lie 2³² apart, far from the seeds one draw takes for η's fresh noise (`seed + 1 + step`),
/// so no two draws share noise.
pub fn draw_seed(seed: u64, draw: usize) -> u64 {
    seed.wrapping_add((draw as u64) << 32)
}

/// How a forecast runs its condition frames through the network.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ContextPasses {
    /// Once per forecast, their temporal keys and values cached (`ContextCache`).
    Cached,
    /// Again at every step, with the future frames, as the plain loop does: to measure what
    /// the cache saves, and to check that it changes nothing.
    EveryStep,
}

/// Samples the N future latents (standardised). Condition frames are never altered: they
/// enter at level 0. With more than one step they run through the network once per forecast,
/// not once per step; with one step there is nothing to reuse, and the one pass over all
/// frames is as fast (measured: bench/results/speed-vs-error.md).
// -> [B, N, C', H, W]
pub fn forecast(
    model: &WorldModel,
    config: &WorldModelConfig,
    schedule: &NoiseSchedule,
    inputs: &ForecastInputs,
    sampler: &DdimConfig,
) -> Result<Tensor<5>, DdimError> {
    let passes = if sampler.steps > 1 {
        ContextPasses::Cached
    } else {
        ContextPasses::EveryStep
    };
    forecast_with(model, config, schedule, inputs, sampler, passes)
}

/// `forecast`, running the condition frames as `passes` says whatever the step count.
pub fn forecast_with(
    model: &WorldModel,
    config: &WorldModelConfig,
    schedule: &NoiseSchedule,
    inputs: &ForecastInputs,
    sampler: &DdimConfig,
    passes: ContextPasses,
) -> Result<Tensor<5>, DdimError> {
    sampler.check(schedule)?;
    let [batch, context, channels, height, width] = inputs.context.dims();
    let future = config.future_frames;
    let device = inputs.context.device();
    let shape = [batch, future, channels, height, width];
    let mut x = seeded_noise(sampler.seed, shape, &device);
    let target = config.diffusion.target;
    let plan = timesteps(schedule.steps(), sampler.steps, sampler.spacing);
    let cache = (passes == ContextPasses::Cached).then(|| {
        model.context(
            inputs.context.clone(),
            inputs.actions.clone().narrow(1, 0, context),
        )
    });
    let future_actions = inputs.actions.clone().narrow(1, context, future);
    // The default, an empty selection, is no fine tokens for any item.
    let selection = if inputs.fine_tokens.tokens.is_empty() {
        FineTokenSelection::none(batch)
    } else {
        inputs.fine_tokens.clone()
    };
    for (index, &(level, previous)) in plan.iter().enumerate() {
        let output = match &cache {
            Some(cache) => model.forward_future_selected(
                cache,
                x.clone(),
                future_actions.clone(),
                &vec![level as f32; batch * future],
                Some(inputs.warped.clone()),
                &selection,
            ),
            None => {
                let levels: Vec<f32> = (0..batch)
                    .flat_map(|_| {
                        std::iter::repeat_n(0.0, context)
                            .chain(std::iter::repeat_n(level as f32, future))
                    })
                    .collect();
                let frames = Tensor::cat(vec![inputs.context.clone(), x.clone()], 1);
                model.forward_selected(
                    frames,
                    inputs.actions.clone(),
                    &levels,
                    future,
                    Some(inputs.warped.clone()),
                    &selection,
                )
            }
        };
        let (clean, noise) = clean_and_noise(schedule, target, x, output, level);
        let fresh = (sampler.eta > 0.0 && previous > 0)
            .then(|| seeded_noise(sampler.seed.wrapping_add(1 + index as u64), shape, &device));
        x = step(schedule, clean, noise, level, previous, sampler.eta, fresh);
    }
    Ok(match &inputs.base {
        Some(base) => {
            let residual = match &sampler.shrink {
                Some(shrink) => shrink.apply(x, config.frame_interval_s),
                None => x,
            };
            residual + base.clone()
        }
        None => x,
    })
}
