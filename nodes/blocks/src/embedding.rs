//! Fixed sinusoidal embeddings: of diffusion timesteps (DiT, after Vaswani et al.), and of
//! token positions in time (1D) and over the BEV plane (2D, MAE's layout). They are computed,
//! never learned, so they exist for any frame count and any grid.

use burn::prelude::*;

/// `[cos(t·ω_0), …, cos(t·ω_{h−1}), sin(t·ω_0), …, sin(t·ω_{h−1})]` with
/// `ω_i = max_period^(−i/h)`, `h = dim / 2`: the embedding of diffusion timestep `t` (DiT's
/// `timestep_embedding`, max period 10,000). An odd `dim` gets a trailing zero.
// timesteps: [N] -> [N, dim]
pub fn timestep_embedding(timesteps: &[f32], dim: usize, device: &Device) -> Tensor<2> {
    let half = dim / 2;
    let mut values = Vec::with_capacity(timesteps.len() * dim);
    for &t in timesteps {
        values.extend(angles(f64::from(t), half).map(|a| a.cos() as f32));
        values.extend(angles(f64::from(t), half).map(|a| a.sin() as f32));
        if dim % 2 == 1 {
            values.push(0.0);
        }
    }
    Tensor::from_data(TensorData::new(values, [timesteps.len(), dim]), device)
}

/// The fixed 1D position encoding of MAE and the original Transformer:
/// `[sin(p·ω_0), …, sin(p·ω_{h−1}), cos(p·ω_0), …, cos(p·ω_{h−1})]`, `ω_i = 10000^(−i/h)`,
/// `h = dim / 2`, for each position `p` (any count: the frame count changes between training
/// stages). `dim` must be even.
pub fn sinusoidal_rows(positions: &[f64], dim: usize) -> Vec<f32> {
    let half = dim / 2;
    let mut values = Vec::with_capacity(positions.len() * dim);
    for &p in positions {
        values.extend(angles(p, half).map(|a| a.sin() as f32));
        values.extend(angles(p, half).map(|a| a.cos() as f32));
    }
    values
}

/// `p · ω_i` for `ω_i = 10000^(−i/half)`, `i < half`.
fn angles(p: f64, half: usize) -> impl Iterator<Item = f64> {
    (0..half).map(move |i| p * (-(10_000f64).ln() * i as f64 / half.max(1) as f64).exp())
}

/// `sinusoidal_rows` of positions `0..count` as a tensor.
// -> [count, dim]
pub fn sinusoidal_1d(count: usize, dim: usize, device: &Device) -> Tensor<2> {
    let positions: Vec<f64> = (0..count).map(|p| p as f64).collect();
    Tensor::from_data(
        TensorData::new(sinusoidal_rows(&positions, dim), [count, dim]),
        device,
    )
}

/// The fixed 2D encoding of an `height × width` token grid, row-major: the first half of the
/// channels encodes the row, the second half the column (MAE's `get_2d_sincos_pos_embed`).
/// `dim` must be a multiple of 4.
// -> [height · width, dim]
pub fn sinusoidal_2d(height: usize, width: usize, dim: usize, device: &Device) -> Tensor<2> {
    let half = dim / 2;
    let rows = sinusoidal_rows(&(0..height).map(|p| p as f64).collect::<Vec<_>>(), half);
    let columns = sinusoidal_rows(&(0..width).map(|p| p as f64).collect::<Vec<_>>(), half);
    let mut values = Vec::with_capacity(height * width * dim);
    for y in 0..height {
        for x in 0..width {
            values.extend_from_slice(&rows[y * half..(y + 1) * half]);
            values.extend_from_slice(&columns[x * half..(x + 1) * half]);
        }
    }
    Tensor::from_data(TensorData::new(values, [height * width, dim]), device)
}
