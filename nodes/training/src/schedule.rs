//! The learning rate at each step: linear warm-up, then cosine decay to a floor.

/// `lr · step / warmup` during warm-up, then
/// `lr · (f + (1 − f) · ½(1 + cos(π · progress)))` with `f = final_fraction`.
pub fn learning_rate(
    lr: f64,
    warmup: usize,
    total: usize,
    final_fraction: f64,
    step: usize,
) -> f64 {
    if warmup > 0 && step < warmup {
        return lr * (step + 1) as f64 / warmup as f64;
    }
    let span = total.saturating_sub(warmup).max(1) as f64;
    let progress = ((step - warmup.min(step)) as f64 / span).clamp(0.0, 1.0);
    let cosine = 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
    lr * (final_fraction + (1.0 - final_fraction) * cosine)
}
