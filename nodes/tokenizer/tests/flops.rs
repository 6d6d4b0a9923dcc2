//! FLOP counts against hand arithmetic.

use crate::common;

use common::model_config as config;

use bevworld_tokenizer::flops::{TokenizerFlops, swin_block};

#[test]
fn a_swin_block_counts_its_four_matmul_groups_over_padded_windows() {
    // dim 2, window 2, a 2 x 2 map: 4 tokens, each attending to 4.
    // qkv 2·4·2·6 = 96, QKᵀ and AV 2·2·4·4·2 = 128, projection 2·4·2·2 = 32,
    // MLP 2·2·4·2·8 = 256.
    assert_eq!(swin_block(2, 2, 2, 2), 512.0);
    // A 3 x 2 map pads to 4 x 2: twice the tokens.
    assert_eq!(swin_block(2, 2, 3, 2), 1024.0);
}

#[test]
fn paper_size_counts_match_hand_arithmetic() {
    let paper = config("paper");
    let flops = TokenizerFlops::of(&paper, 20_000, 20);
    // The head: 2 · 192² cells · 128 · 4096.
    let head = 2.0 * 192.0 * 192.0 * 128.0 * 4096.0;
    // The lift is that head, plus the Swin blocks at 96² (dim 256) and 192² (dim 128), plus
    // the input projection and patch expanding.
    let d = &paper.decoder;
    let blocks = d.depths[0] as f64 * swin_block(256, d.window, 96, 96)
        + d.depths[1] as f64 * swin_block(128, d.window, 192, 192);
    let small = 2.0 * 96.0 * 96.0 * (4.0 * 256.0 + 256.0 * 512.0);
    assert_eq!(flops.lift, head + blocks + small);
    assert!(
        head > swin_block(256, d.window, 96, 96),
        "the head is the largest layer"
    );
    // Sample cost at C_v = 16 and a hidden alpha layer of `alpha_hidden`.
    let h = paper.render.alpha_hidden as f64;
    assert_eq!(
        flops.per_sample,
        2.0 * 8.0 * 16.0 + 2.0 * (16.0 * h + h) + 2.0 * 17.0
    );
    // The pillar net: 20,000 pillars x 20 points x 9 features x 64 channels x 2.
    assert_eq!(
        flops.pillar_net,
        2.0 * 20_000.0 * 20.0 * 9.0 * paper.pillar_channels as f64
    );
    let tiny = TokenizerFlops::of(&config("tiny"), 3000, 20);
    assert!(tiny.encoder() < flops.encoder() / 100.0);
}
