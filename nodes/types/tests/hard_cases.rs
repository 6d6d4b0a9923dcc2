//! The latent statistics' hard case: a channel that never varies. Standardising divides by
//! its deviation, so it is refused wherever statistics are made or read, naming the channel
//! or the field, and never becomes a division by zero downstream.

use bevworld_types::{LatentStats, LatentStatsAccumulator, LatentStatsError, LatentStatsFile};

#[test]
fn a_channel_that_never_varies_is_refused_when_the_statistics_are_made() {
    let mut accumulator = LatentStatsAccumulator::default();
    // Two channels of four cells; channel 1 is 0.5 everywhere, in both latents.
    accumulator
        .add(&[1.0, 2.0, 3.0, 4.0, 0.5, 0.5, 0.5, 0.5], 2)
        .expect("first");
    accumulator
        .add(&[0.0, -1.0, 5.0, 2.0, 0.5, 0.5, 0.5, 0.5], 2)
        .expect("second");
    let error = accumulator.finish().expect_err("refused");
    assert_eq!(
        error,
        LatentStatsError::ZeroVariance {
            channel: 1,
            value: 0.5
        }
    );
    assert!(error.to_string().contains("channel 1"), "{error}");
}

#[test]
fn a_statistics_file_with_a_zero_deviation_is_refused_naming_the_field() {
    let dir = tempfile::tempdir().expect("dir");
    let path = dir.path().join("w.stats.json");
    let file = LatentStatsFile {
        model: "tokenizer-tiny".into(),
        weights_hash: "abc".into(),
        data: "out/synth".into(),
        stats: LatentStats {
            mean: vec![0.0, 1.0, 2.0, 3.0],
            std: vec![1.0, 0.0, 1.0, 1.0],
            frames: 4,
        },
    };
    let text = serde_json::to_string(&file).expect("json");
    std::fs::write(&path, text).expect("write");
    let message = LatentStatsFile::load(&path)
        .expect_err("refused")
        .to_string();
    assert!(
        message.contains("w.stats.json") && message.contains("stats.std"),
        "{message}"
    );
    // And the deviation it would have divided by, made tiny instead of zero, is refused the
    // same way only when it is not a finite positive number: 1e-30 is a valid, if extreme,
    // deviation and standardises to finite values.
    let tiny = LatentStats {
        mean: vec![0.0],
        std: vec![1e-30],
        frames: 1,
    };
    let mut values = vec![1e-30f32];
    tiny.standardize(&mut values);
    assert!(values.iter().all(|v| v.is_finite()), "{values:?}");
}
