//! Action control with ground truth: `bevworld synth --branch-at` writes one scene per
//! manoeuvre, byte-identical to the unbranched scene up to the branch and different after
//! it, and `bevworld eval control` finds the shipped world model's `left` and `right`
//! forecasts each closest to their own truth.

use crate::common;

use std::path::Path;

use common::{bevworld_owned, text};

fn path(p: &Path) -> String {
    p.display().to_string()
}

fn synth(out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args: Vec<String> = [
        "synth",
        "--out",
        &path(out),
        "--seed",
        "9730",
        "--seconds",
        "3",
        "--camera-size",
        "224x126",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    args.extend(extra.iter().map(|s| s.to_string()));
    bevworld_owned(&args)
}

/// `(timestamp, bytes)` of every sensor file of `scene` in `data`, by channel and time.
fn files(data: &Path, scene: &str) -> Vec<(String, i64, Vec<u8>)> {
    let mut files = Vec::new();
    for folder in ["samples", "sweeps"] {
        for channel in std::fs::read_dir(data.join(folder)).expect("folder") {
            let channel = channel.expect("entry").path();
            for file in std::fs::read_dir(&channel).expect("channel") {
                let file = file.expect("entry").path();
                let name = file
                    .file_name()
                    .expect("name")
                    .to_string_lossy()
                    .to_string();
                let Some(rest) = name.strip_prefix(&format!("{scene}__")) else {
                    continue;
                };
                let time: i64 = rest
                    .split("__")
                    .nth(1)
                    .and_then(|t| t.split('.').next())
                    .and_then(|t| t.parse().ok())
                    .expect("timestamp");
                let key = format!("{folder}/{}", rest.split("__").next().expect("channel"));
                files.push((key, time, std::fs::read(&file).expect("read")));
            }
        }
    }
    files.sort_by(|a, b| (&a.0, a.1).cmp(&(&b.0, b.1)));
    files
}

#[test]
fn branches_share_the_past_and_a_forecast_follows_its_own_manoeuvre() {
    let dir = tempfile::tempdir().expect("dir");
    let (plain, branched) = (dir.path().join("plain"), dir.path().join("branched"));
    let output = synth(&plain, &[]);
    assert!(output.status.success(), "{}", text(&output));
    let output = synth(
        &branched,
        &["--branch-at", "1.5", "--manoeuvres", "keep,left,right"],
    );
    assert!(output.status.success(), "{}", text(&output));

    // 1.5 s is tick 18 of the 12 Hz clock.
    let t0: i64 = 1_700_000_000_000_000 + 9730 * 1_000_000;
    let branch_us = t0 + 18 * 83_333;
    let original = files(&plain, "synth-009730");
    assert_eq!(original.len(), 36 * 7);
    for manoeuvre in ["keep", "left", "right"] {
        let branch = files(&branched, &format!("synth-009730-{manoeuvre}"));
        assert_eq!(branch.len(), original.len());
        let (mut before, mut after_differing) = (0, 0);
        for (a, b) in original.iter().zip(&branch) {
            assert_eq!((&a.0, a.1), (&b.0, b.1));
            if a.1 < branch_us {
                assert!(
                    a.2 == b.2,
                    "{manoeuvre}: {} at {} differs before the branch",
                    a.0,
                    a.1
                );
                before += 1;
            } else {
                after_differing += usize::from(a.2 != b.2);
            }
        }
        assert!(before > 100, "{before}");
        // Every LiDAR sweep after the branch sees the world from elsewhere.
        let lidar_after = branch
            .iter()
            .filter(|f| f.0.ends_with("LIDAR_TOP") && f.1 > branch_us)
            .count();
        assert!(
            after_differing >= lidar_after,
            "{manoeuvre}: {after_differing} files differ after the branch"
        );
    }

    // `eval control` at 1 s by `method`, its JSON.
    let control = |method: &str| -> serde_json::Value {
        let output = bevworld_owned(&[
            "eval".into(),
            "control".into(),
            "--data".into(),
            path(&branched),
            "--horizon".into(),
            "1".into(),
            "--method".into(),
            method.into(),
            "--out".into(),
            path(&dir.path().join(format!("control-{method}"))),
            "--json".into(),
        ]);
        assert!(output.status.success(), "{}", text(&output));
        serde_json::from_slice(&output.stdout).expect("json")
    };

    // The context is the last shared keyframe (1.5 s); 1 s later the truths differ.
    let result = control("model");
    assert_eq!(result["pairs"], 3, "{result}");
    let by_name = |name: &str| {
        result["manoeuvres"]
            .as_array()
            .expect("manoeuvres")
            .iter()
            .find(|m| m["manoeuvre"] == name)
            .cloned()
            .expect(name)
    };
    for turn in ["left", "right"] {
        assert_eq!(by_name(turn)["accuracy"], 1.0, "{result}");
        assert!(
            by_name(turn)["swap_ratio"].as_f64().expect("ratio") > 1.5,
            "{result}"
        );
    }

    // The floor: the tokenizer's latent of each branch's own true frame, rendered along that
    // frame's rays, lies nearer its truth than any forecast does, and tells every branch apart.
    let oracle = control("oracle");
    assert_eq!(oracle["method"], "oracle");
    assert_eq!(
        (oracle["pairs"].clone(), oracle["accuracy"].clone()),
        (3.into(), 1.0.into()),
        "{oracle}"
    );
    let own = |table: &serde_json::Value, m: &str| {
        table["distances"]["synth-009730"][m][m]
            .as_f64()
            .expect("own distance")
    };
    for m in ["keep", "left", "right"] {
        assert!(
            own(&oracle, m) < own(&result, m),
            "{m}: {oracle} against {result}"
        );
    }
}

#[test]
fn branching_and_control_refuse_what_they_cannot_do() {
    let dir = tempfile::tempdir().expect("dir");
    // The American spelling is the same flag: its values reach the same check.
    let output = synth(
        &dir.path().join("a"),
        &["--branch-at", "1", "--maneuvers", "keep,sideways"],
    );
    assert!(!output.status.success());
    assert!(
        text(&output).contains("--manoeuvres: unknown manoeuvre 'sideways'")
            && text(&output).contains("known: keep, left, right, faster, slower, stop"),
        "{}",
        text(&output)
    );
    let output = synth(&dir.path().join("b"), &["--manoeuvres", "left"]);
    assert!(!output.status.success());
    assert!(text(&output).contains("--branch-at"), "{}", text(&output));
    let output = synth(&dir.path().join("c"), &["--branch-at", "5"]);
    assert!(!output.status.success());
    assert!(
        text(&output).contains("branch at: 5 s"),
        "{}",
        text(&output)
    );
    let output = synth(
        &dir.path().join("d"),
        &["--branch-at", "1", "--manoeuvres", "left,left"],
    );
    assert!(!output.status.success());
    assert!(
        text(&output).contains("left named twice"),
        "{}",
        text(&output)
    );
    assert!(!dir.path().join("a").exists() && !dir.path().join("c").exists());

    // An unbranched dataset has nothing to compare.
    let plain = dir.path().join("plain");
    let output = bevworld_owned(&[
        "synth".into(),
        "--out".into(),
        path(&plain),
        "--seconds".into(),
        "0.5".into(),
        "--camera-size".into(),
        "64x36".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let output = bevworld_owned(&[
        "eval".into(),
        "control".into(),
        "--data".into(),
        path(&plain),
    ]);
    assert!(!output.status.success());
    assert!(
        text(&output).contains("no branched scenes"),
        "{}",
        text(&output)
    );
}
