//! The world model's graph nodes: `latent_history` keeps a scene's recent latents and emits
//! windows, `diffusion_rollout` forecasts from a window, and `future_views` pairs each future
//! latent with the rays it is rendered along (the logged future frame, or the rig at the
//! predicted pose) and with the truth it is scored against; `move_agents` carries the detected
//! agents of a forecast along their predicted trajectories.

pub mod diffusion_rollout;
pub mod future_views;
pub mod latent_history;
pub mod model_params;
pub mod move_agents;

pub fn register(registry: &mut bevworld_graph::Registry) {
    latent_history::register(registry);
    diffusion_rollout::register(registry);
    future_views::register(registry);
    move_agents::register(registry);
}
