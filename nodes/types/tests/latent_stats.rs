//! The latent's normalisation statistics against hand-computed values, and their file, which
//! names the weights it belongs to.

use bevworld_types::{
    LatentStats, LatentStatsAccumulator, LatentStatsFile, StatsFileError, stats_path_for,
};

#[test]
fn statistics_match_hand_computation_in_any_order() {
    // Two latents of 2 channels x 4 cells. Channel 0 holds 1..8 overall, channel 1 seven 3s
    // and a 5 (a constant channel is refused: `hard_cases.rs`).
    let first = [1.0f32, 2.0, 3.0, 4.0, 3.0, 3.0, 3.0, 3.0];
    let second = [5.0f32, 6.0, 7.0, 8.0, 3.0, 3.0, 3.0, 5.0];
    let mut forward = LatentStatsAccumulator::default();
    forward.add(&first, 2).unwrap();
    forward.add(&second, 2).unwrap();
    let stats = forward.finish().unwrap();
    assert_eq!(stats.frames, 2);
    assert!((stats.mean[0] - 4.5).abs() < 1e-12);
    // Population variance of 1..8 is 5.25.
    assert!((stats.std[0] - 5.25f64.sqrt()).abs() < 1e-12);
    // Mean 26 / 8; variance 88 / 8 − 3.25².
    assert!((stats.mean[1] - 3.25).abs() < 1e-12);
    assert!((stats.std[1] - 0.4375f64.sqrt()).abs() < 1e-12);

    let mut backward = LatentStatsAccumulator::default();
    backward.add(&second, 2).unwrap();
    backward.add(&first, 2).unwrap();
    let reversed = backward.finish().unwrap();
    assert!((reversed.mean[0] - stats.mean[0]).abs() < 1e-12);
    assert!((reversed.std[0] - stats.std[0]).abs() < 1e-12);

    // Standardising and back restores the latent.
    let mut latent = first;
    stats.standardize(&mut latent);
    assert!((latent[0] - ((1.0 - 4.5) / 5.25f64.sqrt()) as f32).abs() < 1e-6);
    assert!(latent.iter().all(|v| v.is_finite()));
    let mut restored = latent;
    stats.destandardize(&mut restored);
    for (a, b) in restored.iter().zip(first) {
        assert!((a - b).abs() < 1e-6);
    }
}

#[test]
fn statistics_refuse_bad_latents() {
    let mut acc = LatentStatsAccumulator::default();
    assert!(acc.finish().is_err());
    assert!(acc.add(&[1.0, 2.0, 3.0], 2).is_err());
    acc.add(&[1.0, 2.0, 3.0, 4.0], 2).unwrap();
    assert!(
        acc.add(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 3)
            .unwrap_err()
            .to_string()
            .contains("3 channels")
    );
    assert!(
        acc.add(&[f32::NAN, 1.0, 2.0, 3.0], 2)
            .unwrap_err()
            .to_string()
            .contains("non-finite")
    );
    assert_eq!(acc.finish().unwrap().frames, 1);
}

#[test]
fn stats_files_round_trip_and_refuse_bad_fields_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = stats_path_for(&dir.path().join("w.bpk"));
    assert!(path.ends_with("w.stats.json"));
    assert!(matches!(
        LatentStatsFile::load(&path),
        Err(StatsFileError::NotFound { .. })
    ));
    let file = LatentStatsFile {
        model: "tokenizer-tiny".into(),
        weights_hash: "abc".into(),
        data: "out/synth".into(),
        stats: LatentStats {
            mean: vec![0.5, -1.0],
            std: vec![2.0, 0.25],
            frames: 3,
        },
    };
    file.save(&path).expect("save");
    assert_eq!(LatentStatsFile::load(&path).expect("load"), file);

    let broken = |text: &str| -> String {
        std::fs::write(&path, text).expect("write");
        LatentStatsFile::load(&path)
            .expect_err("refused")
            .to_string()
    };
    let good = serde_json::to_value(&file).expect("json");
    let mut zero_std = good.clone();
    zero_std["stats"]["std"][1] = serde_json::json!(0.0);
    assert!(broken(&zero_std.to_string()).contains("stats.std"));
    let mut short = good.clone();
    short["stats"]["mean"] = serde_json::json!([0.5]);
    assert!(broken(&short.to_string()).contains("stats.std"));
    let mut wrong_type = good.clone();
    wrong_type["stats"]["frames"] = serde_json::json!("three");
    let message = broken(&wrong_type.to_string());
    assert!(message.contains("stats.frames"), "{message}");
    assert!(broken("{").contains("w.stats.json"));
}
