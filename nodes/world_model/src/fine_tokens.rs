//! Sparse fine tokens: which coarse tokens of a scene get fine ones.
//!
//! A coarse token covers `p × p` latent cells (10 m × 10 m for the tiny model), a car a
//! fraction of one. Most of a scene does not move: once the ego motion is taken out, the static
//! world is the same latent from frame to frame, and the ego warp carries it. What moves shows
//! in the context itself: a cell whose latent changes between two condition frames after the
//! earlier one is warped into the later one's ego frame holds something that moved (or was
//! uncovered by something that moved). Those tokens, and their neighbours, where the mover may
//! go, get one fine token per latent cell (`fine_stage.rs`); the rest get none.
//!
//! The rule reads only the model's own input (the standardised context and the ego motion
//! between its frames), so training and forecasting select alike, and a static context selects
//! nothing.

use bevworld_types::ConfigProblem;
use bevworld_types::bev_warp::{LatentGrid, PlanarMotion, warp_taps};
use bevworld_types::problem::require_count;
use serde::{Deserialize, Serialize};

use crate::config::require_token_width;

/// A cell's warp counts only where all of its bilinear taps fall inside the earlier frame's
/// grid: a cell that enters the grid as the ego drives changes by construction, not by motion.
const INSIDE: f32 = 0.999;

/// The fine stage of a world model (`fine_tokens:` in the model YAML).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FineTokensConfig {
    /// Fine token width.
    pub width: usize,
    /// Fine blocks (temporal and spatial attention within a coarse token's cells, and an MLP).
    pub depth: usize,
    pub heads: usize,
    /// Which coarse tokens get fine ones.
    pub select: FineTokenRule,
}

/// Which coarse tokens get fine ones: those where the context moves more than `threshold`,
/// and the tokens within `dilate` of them.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FineTokenRule {
    /// The change of a standardised latent cell between two condition frames, summed over its
    /// channels, above which its token moves (`motion_score`).
    pub threshold: f32,
    /// Tokens (Chebyshev distance on the token grid) around a moving one that also get fine
    /// tokens: where a mover may be in the future frames.
    pub dilate: usize,
}

impl FineTokensConfig {
    /// Every inconsistency, the fields named under `fine_tokens.`.
    pub fn problems(&self) -> Vec<ConfigProblem> {
        let mut problems = Vec::new();
        for (field, value) in [
            ("fine_tokens.width", self.width),
            ("fine_tokens.depth", self.depth),
            ("fine_tokens.heads", self.heads),
        ] {
            require_count(&mut problems, field, value);
        }
        require_token_width(
            &mut problems,
            ("fine_tokens.width", self.width),
            ("fine_tokens.heads", self.heads),
        );
        let threshold = self.select.threshold;
        if !(threshold.is_finite() && threshold >= 0.0) {
            problems.push(ConfigProblem::new(
                "fine_tokens.select.threshold",
                format!("{threshold} (accepted: a finite value ≥ 0)"),
            ));
        }
        problems
    }
}

/// The coarse tokens that get fine tokens, per batch item, ascending (token index row-major
/// over the token grid).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FineTokenSelection {
    pub tokens: Vec<Vec<usize>>,
}

impl FineTokenSelection {
    /// No fine tokens for `batch` items.
    pub fn none(batch: usize) -> Self {
        Self {
            tokens: vec![Vec::new(); batch],
        }
    }

    /// The selected tokens of all items.
    pub fn count(&self) -> usize {
        self.tokens.iter().map(Vec::len).sum()
    }

    /// The selected share of `tokens_per_item · items` tokens.
    pub fn share(&self, tokens_per_item: usize) -> f64 {
        let all = tokens_per_item * self.tokens.len();
        if all == 0 {
            0.0
        } else {
            self.count() as f64 / all as f64
        }
    }

    /// Each selected token's row in a `[B·L, …]` layout (`b·L + l`), and its item `b`.
    pub fn rows_and_items(&self, tokens_per_item: usize) -> (Vec<i64>, Vec<i64>) {
        self.tokens
            .iter()
            .enumerate()
            .flat_map(|(b, tokens)| {
                tokens
                    .iter()
                    .map(move |&l| ((b * tokens_per_item + l) as i64, b as i64))
            })
            .unzip()
    }
}

/// How much each latent cell moves in a context: for every pair of consecutive condition
/// frames, `Σ_c |x_k − warp(x_{k−1})|`, the earlier frame moved into the later one's ego frame
/// (`previous_from_frame[k − 1]`, the ego motion into frame k), and the largest over the pairs.
/// Cells whose warp reaches outside the earlier frame score 0.
// context: [P+1, C, H, W] standardised, previous_from_frame: P motions -> [H, W]
pub fn motion_score(
    context: &[f32],
    grid: &LatentGrid,
    previous_from_frame: &[PlanarMotion],
) -> Vec<f32> {
    let plane = grid.height * grid.width;
    let frame = grid.len();
    let mut score = vec![0.0f32; plane];
    for (k, motion) in previous_from_frame.iter().enumerate() {
        let (Some(previous), Some(current)) = (
            context.get(k * frame..(k + 1) * frame),
            context.get((k + 1) * frame..(k + 2) * frame),
        ) else {
            break;
        };
        for (cell, taps) in warp_taps(grid, motion).iter().enumerate() {
            let inside: f32 = taps.iter().map(|&(_, w)| w).sum();
            if inside < INSIDE {
                continue;
            }
            let change: f32 = (0..grid.channels)
                .map(|c| {
                    let source = &previous[c * plane..(c + 1) * plane];
                    let warped: f32 = taps.iter().map(|&(i, w)| w * source[i as usize]).sum();
                    (current[c * plane + cell] - warped).abs()
                })
                .sum();
            score[cell] = score[cell].max(change);
        }
    }
    score
}

/// The tokens of a `[H, W]` cell score that `rule` selects, ascending: those holding a cell
/// above the threshold, dilated by `rule.dilate` tokens.
pub fn select_tokens(
    score: &[f32],
    size: [usize; 2],
    patch: usize,
    rule: &FineTokenRule,
) -> Vec<usize> {
    let patch = patch.max(1);
    let [rows, columns] = [size[0] / patch, size[1] / patch];
    let mut moving = vec![false; rows * columns];
    for (cell, &value) in score.iter().enumerate() {
        let (y, x) = (cell / size[1], cell % size[1]);
        if value > rule.threshold && y / patch < rows && x / patch < columns {
            moving[(y / patch) * columns + x / patch] = true;
        }
    }
    let r = rule.dilate;
    (0..rows * columns)
        .filter(|&token| {
            let (ty, tx) = (token / columns, token % columns);
            let ys = ty.saturating_sub(r)..(ty + r + 1).min(rows);
            ys.into_iter().any(|y| {
                (tx.saturating_sub(r)..(tx + r + 1).min(columns)).any(|x| moving[y * columns + x])
            })
        })
        .collect()
}

/// The fine tokens a context gets: `select_tokens` of its `motion_score`.
// context: [P+1, C, H, W] standardised, previous_from_frame: P motions
pub fn select_for_context(
    context: &[f32],
    grid: &LatentGrid,
    previous_from_frame: &[PlanarMotion],
    patch: usize,
    rule: &FineTokenRule,
) -> Vec<usize> {
    let score = motion_score(context, grid, previous_from_frame);
    select_tokens(&score, [grid.height, grid.width], patch, rule)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> LatentGrid {
        LatentGrid {
            channels: 2,
            height: 8,
            width: 8,
            x_range: [-8.0, 8.0],
            y_range: [-8.0, 8.0],
        }
    }

    fn rule(threshold: f32, dilate: usize) -> FineTokenRule {
        FineTokenRule { threshold, dilate }
    }

    #[test]
    fn a_static_context_selects_no_token_even_while_the_ego_drives() {
        let grid = grid();
        // A constant latent (the same in every frame) and the ego driving 2 m a frame: every
        // inside cell warps onto the same value, and the cells entering the grid do not count.
        let context = vec![0.7f32; 3 * grid.len()];
        let drive = PlanarMotion {
            x: 2.0,
            y: 0.0,
            yaw: 0.0,
        };
        let score = motion_score(&context, &grid, &[drive, drive]);
        assert!(score.iter().all(|&s| s == 0.0), "{score:?}");
        assert!(select_for_context(&context, &grid, &[drive, drive], 2, &rule(0.0, 1)).is_empty());
    }

    #[test]
    fn one_moving_box_selects_its_tokens_and_their_dilation() {
        let grid = grid();
        let plane = 64;
        // Frame 0 empty; frame 1 holds a box in cells (y 2..4, x 5): channel 0 = 1, channel 1
        // = 0.5, so its change is 1.5 per cell; the ego stands still.
        let mut context = vec![0.0f32; 2 * grid.len()];
        for y in 2..4 {
            let cell = y * 8 + 5;
            context[grid.len() + cell] = 1.0;
            context[grid.len() + plane + cell] = 0.5;
        }
        let still = [PlanarMotion::default()];
        let score = motion_score(&context, &grid, &still);
        for (cell, &s) in score.iter().enumerate() {
            let expected = if [21, 29].contains(&cell) { 1.5 } else { 0.0 };
            assert_eq!(s, expected, "cell {cell}");
        }
        // Patch 2: the 4 × 4 token grid; cells (2..4, 5) lie in token row 1, column 2.
        assert_eq!(
            select_for_context(&context, &grid, &still, 2, &rule(1.0, 0)),
            vec![6]
        );
        // Dilated by one: rows 0..=2, columns 1..=3.
        assert_eq!(
            select_for_context(&context, &grid, &still, 2, &rule(1.0, 1)),
            vec![1, 2, 3, 5, 6, 7, 9, 10, 11]
        );
        // Above the box's change: nothing.
        assert!(select_for_context(&context, &grid, &still, 2, &rule(1.5, 1)).is_empty());
    }

    #[test]
    fn the_score_is_the_largest_change_over_the_frame_pairs() {
        let grid = grid();
        let mut context = vec![0.0f32; 3 * grid.len()];
        // Cell 10 goes 0 → 2 → 1.5: changes 2 then 0.5, channel 0 only.
        context[grid.len() + 10] = 2.0;
        context[2 * grid.len() + 10] = 1.5;
        let still = [PlanarMotion::default(); 2];
        assert_eq!(motion_score(&context, &grid, &still)[10], 2.0);
    }

    #[test]
    fn the_selection_counts_and_lays_out_its_rows() {
        let selection = FineTokenSelection {
            tokens: vec![vec![1, 3], vec![], vec![0]],
        };
        assert_eq!(selection.count(), 3);
        assert!((selection.share(4) - 0.25).abs() < 1e-12);
        assert_eq!(selection.rows_and_items(4), (vec![1, 3, 8], vec![0, 0, 2]));
        assert_eq!(FineTokenSelection::none(2).count(), 0);
    }

    #[test]
    fn bad_fine_settings_are_refused_by_field() {
        let config = FineTokensConfig {
            width: 30,
            depth: 0,
            heads: 4,
            select: rule(f32::NAN, 1),
        };
        let fields: Vec<String> = config.problems().iter().map(|p| p.field.clone()).collect();
        assert_eq!(
            fields,
            [
                "fine_tokens.depth",
                "fine_tokens.heads",
                "fine_tokens.width",
                "fine_tokens.select.threshold"
            ]
        );
    }
}
