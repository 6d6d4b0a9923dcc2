//! The committed model configs parse, are consistent, and give the paper's sizes; a broken
//! config names every bad field.

use std::path::PathBuf;

use bevworld_tokenizer::Modality;
use bevworld_tokenizer::config::{ConfigError, TokenizerConfig};

fn model(name: &str) -> PathBuf {
    PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"))
        .join("../../configs/models")
        .join(name)
}

#[test]
fn paper_config_has_the_papers_sizes() {
    let config = TokenizerConfig::from_yaml_file(&model("tokenizer-paper.yaml")).expect("paper");
    assert_eq!(config.latent_size(), 96);
    assert_eq!(config.latent_channels, 4);
    assert_eq!(config.fused_channels(), 256);
    assert_eq!(config.voxel_shape(), [16, 64, 384, 384]);
    assert_eq!(config.decoder.block_channels(), 4096);
    assert_eq!(config.image_backbone.out_channels(), 768);
    assert_eq!(config.image_feature_size(), [8, 22]);
    assert_eq!(config.render.samples, 150);
    let placement = config.voxel_placement();
    assert!((placement.voxel_size[0] - 160.0 / 384.0).abs() < 1e-6);
    assert!((placement.voxel_size[2] - 9.0 / 64.0).abs() < 1e-6);
}

#[test]
fn tiny_config_is_consistent() {
    let config = TokenizerConfig::from_yaml_file(&model("tokenizer-tiny.yaml")).expect("tiny");
    assert_eq!(config.latent_size(), 64);
    assert_eq!(config.voxel_shape(), [8, 32, 128, 128]);
    assert_eq!(config.image_feature_size(), [8, 14]);
    // The shipped weights were trained with the escaping mass adding no depth.
    assert!(!config.render.escape_at_far);
}

#[test]
fn escape_at_far_is_required_checked_and_round_trips() {
    let text = std::fs::read_to_string(model("tokenizer-tiny.yaml")).expect("tiny");
    let set = text.replace("escape_at_far: false", "escape_at_far: true");
    assert_ne!(set, text);
    let config = TokenizerConfig::from_yaml(&set, "set.yaml").expect("parses");
    assert!(config.render.escape_at_far);
    let again =
        TokenizerConfig::from_yaml(&config.to_yaml().expect("yaml"), "again").expect("reads");
    assert_eq!(again, config);
    for (bad, name) in [
        (
            text.replace("escape_at_far: false", "escape_at_far: 3"),
            "wrong.yaml",
        ),
        (text.replace("  escape_at_far: false\n", ""), "missing.yaml"),
    ] {
        let message = TokenizerConfig::from_yaml(&bad, name)
            .expect_err("refused")
            .to_string();
        assert!(message.contains(name), "{message}");
        if name == "missing.yaml" {
            assert!(message.contains("escape_at_far"), "{message}");
        }
    }
}

#[test]
fn a_broken_config_names_every_bad_field() {
    let text = std::fs::read_to_string(model("tokenizer-tiny.yaml")).expect("read");
    let broken = text
        .replace("pillar_grid: 128", "pillar_grid: 129")
        .replace("heads: [2, 4]", "heads: [2, 5]")
        .replace("camera_stride: 4", "camera_stride: 6")
        .replace("linear_until: 20.0", "linear_until: 90.0");
    let err = TokenizerConfig::from_yaml(&broken, "broken.yaml").unwrap_err();
    let message = err.to_string();
    assert!(matches!(err, ConfigError::Invalid { .. }));
    for field in [
        "broken.yaml",
        "bev.pillar_grid",
        "image_backbone.heads[1]",
        "render.camera_stride",
        "render.linear_until",
    ] {
        assert!(message.contains(field), "{field} missing from: {message}");
    }
    let err = TokenizerConfig::from_yaml("name: x\ncameras: six\n", "typo.yaml").unwrap_err();
    assert!(err.to_string().contains("typo.yaml"), "{err}");
    assert!(
        TokenizerConfig::from_yaml_file(&model("absent.yaml"))
            .unwrap_err()
            .to_string()
            .contains("absent.yaml")
    );
}

#[test]
fn modalities_are_both_by_default_and_round_trip() {
    let text = std::fs::read_to_string(model("tokenizer-tiny.yaml")).expect("read");
    let config = TokenizerConfig::from_yaml(&text, "tiny.yaml").expect("tiny");
    assert_eq!(config.modalities, Modality::BOTH);

    let mut camera_only = config.clone();
    camera_only.modalities = vec![Modality::Camera];
    let yaml = camera_only.to_yaml().expect("yaml");
    let back = TokenizerConfig::from_yaml(&yaml, "written.yaml").expect("read back");
    assert_eq!(back, camera_only);
    assert!(back.uses(Modality::Camera) && !back.uses(Modality::Lidar));

    for (line, expected) in [
        ("modalities: []", "modalities: needs"),
        ("modalities: [lidar, lidar]", "names one twice"),
        ("modalities: [radar]", "radar"),
    ] {
        let err = TokenizerConfig::from_yaml(
            &text.replace("modalities: [camera, lidar]", line),
            "ablation.yaml",
        )
        .expect_err(line)
        .to_string();
        assert!(
            err.contains("ablation.yaml") && err.contains(expected),
            "{line}: {err}"
        );
    }
}

#[test]
fn fusion_levels_must_name_stages_the_image_backbone_has() {
    let text = std::fs::read_to_string(model("tokenizer-tiny.yaml")).expect("read");
    let with_levels = |levels: &str| {
        text.lines()
            .map(|line| {
                if line.starts_with("fusion_levels:") {
                    format!("fusion_levels: {levels}")
                } else {
                    line.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
    };
    for levels in ["1", "2"] {
        let config = TokenizerConfig::from_yaml(&with_levels(levels), "levels.yaml")
            .unwrap_or_else(|e| panic!("{levels}: {e}"));
        // The tiny image backbone's two stages: 16 channels at stride 4, 32 at stride 8.
        let fine: Vec<usize> = if levels == "2" { vec![16] } else { vec![] };
        assert_eq!(config.fusion_fine_channels(), fine);
    }
    for levels in ["0", "3"] {
        let message = TokenizerConfig::from_yaml(&with_levels(levels), "levels.yaml")
            .expect_err(levels)
            .to_string();
        assert!(
            message.contains("levels.yaml") && message.contains("fusion_levels: "),
            "{levels}: {message}"
        );
    }
}

#[test]
fn a_misspelt_key_is_refused_by_its_path_not_read_as_a_default() {
    let text = std::fs::read_to_string(model("tokenizer-tiny.yaml")).expect("tiny");
    // A top-level key and a nested one, as a user mistypes them.
    let misspelt = text.replace(
        "  escape_at_far: false",
        "  escape_at_far: false\n  escape_at_fra: true",
    ) + "\nlatent_chanels: 8\n";
    let Err(ConfigError::Invalid { problems, .. }) = TokenizerConfig::from_yaml(&misspelt, "tiny")
    else {
        panic!("a misspelt key was accepted");
    };
    let fields: Vec<&str> = problems.iter().map(|p| p.field.as_str()).collect();
    assert!(fields.contains(&"latent_chanels"), "{fields:?}");
    assert!(fields.contains(&"render.escape_at_fra"), "{fields:?}");
    // Every committed config, and one written back, has none.
    for name in ["tokenizer-tiny.yaml", "tokenizer-paper.yaml"] {
        let config = TokenizerConfig::from_yaml_file(&model(name)).expect(name);
        let written = config.to_yaml().expect("yaml");
        assert_eq!(
            TokenizerConfig::from_yaml(&written, name).expect("round trip"),
            config
        );
    }
}
