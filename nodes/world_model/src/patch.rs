//! Frames to spatial tokens and back: a `[C', H, W]` latent becomes `(H/p)·(W/p)` tokens of
//! `C'·p·p` values, row-major over the token grid, each token's values in (channel, row,
//! column) order.

use burn::prelude::*;

// x: [B, F, C, H, W] -> [B, F, (H/p)·(W/p), C·p·p]
pub fn patchify(x: Tensor<5>, patch: usize) -> Tensor<4> {
    let [batch, frames, channels, height, width] = x.dims();
    let (rows, columns) = (height / patch, width / patch);
    x.reshape([batch, frames, channels, rows, patch, columns, patch])
        .permute([0, 1, 3, 5, 2, 4, 6]) // [B, F, H/p, W/p, C, p, p]
        .reshape([batch, frames, rows * columns, channels * patch * patch])
}

/// The inverse of `patchify`.
// tokens: [B, F, (H/p)·(W/p), C·p·p] -> [B, F, C, H, W]
pub fn unpatchify(tokens: Tensor<4>, patch: usize, channels: usize, size: [usize; 2]) -> Tensor<5> {
    let [batch, frames, _, _] = tokens.dims();
    let (rows, columns) = (size[0] / patch, size[1] / patch);
    tokens
        .reshape([batch, frames, rows, columns, channels, patch, patch])
        .permute([0, 1, 4, 2, 5, 3, 6]) // [B, F, C, H/p, p, W/p, p]
        .reshape([batch, frames, channels, size[0], size[1]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_holds_its_cells_and_unpatchify_inverts() {
        let device = Device::flex();
        // [1, 1, 2, 4, 4]: value = 100·c + 10·y + x.
        let values: Vec<f32> = (0..2)
            .flat_map(|c| {
                (0..4).flat_map(move |y| (0..4).map(move |x| (100 * c + 10 * y + x) as f32))
            })
            .collect();
        let x = Tensor::<5>::from_data(TensorData::new(values.clone(), [1, 1, 2, 4, 4]), &device);
        let tokens = patchify(x, 2);
        assert_eq!(tokens.dims(), [1, 1, 4, 8]);
        // Token 1 is row 0, column 1 of the token grid: cells x 2..4, y 0..2.
        let token: Vec<f32> = tokens
            .clone()
            .narrow(2, 1, 1)
            .into_data()
            .try_to_vec()
            .unwrap();
        assert_eq!(token, vec![2., 3., 12., 13., 102., 103., 112., 113.]);
        let back: Vec<f32> = unpatchify(tokens, 2, 2, [4, 4])
            .into_data()
            .try_to_vec()
            .unwrap();
        assert_eq!(back, values);
    }
}
