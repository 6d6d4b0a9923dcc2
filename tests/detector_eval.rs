//! `bevworld eval detector`: a results file scored against a synthetic set's annotations, and
//! results files that are refused naming what is wrong.

use std::collections::BTreeMap;
use std::path::Path;

use bevworld_metrics::detection::sample_truth;
use bevworld_sensors::{Dataset, DatasetOptions};
use bevworld_types::{Detection, DetectionResults, SubmissionMeta};

use crate::common::{bevworld_owned, text};

fn path(p: &Path) -> String {
    p.display().to_string()
}

/// A small synthetic set, and its scored truth given back as detections of score 0.5.
fn set_and_its_truth(dir: &Path) -> DetectionResults {
    let data = dir.join("data");
    let output = bevworld_owned(&[
        "synth".into(),
        "--out".into(),
        path(&data),
        "--seed".into(),
        "31".into(),
        "--seconds".into(),
        "2".into(),
        "--camera-size".into(),
        "64x36".into(),
    ]);
    assert!(output.status.success(), "{}", text(&output));
    let options = DatasetOptions {
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(&data, &options).expect("opens");
    let mut results = BTreeMap::new();
    for index in 0..dataset.len() {
        let (sample, truth) = sample_truth(&dataset.read(index).expect("frame")).expect("truth");
        let boxes: Vec<Detection> = truth
            .boxes
            .into_iter()
            .filter(|b| b.num_pts > 0)
            .map(|b| Detection {
                detection_score: 0.5,
                velocity: b
                    .detection
                    .velocity
                    .map(|v| if v.is_nan() { 0.0 } else { v }),
                ..b.detection
            })
            .collect();
        results.insert(sample, boxes);
    }
    DetectionResults {
        meta: SubmissionMeta {
            use_lidar: true,
            ..Default::default()
        },
        results,
    }
}

fn eval(dir: &Path, results: &Path) -> std::process::Output {
    bevworld_owned(&[
        "eval".into(),
        "detector".into(),
        "--data".into(),
        path(&dir.join("data")),
        "--results".into(),
        path(results),
        "--json".into(),
    ])
}

#[test]
fn the_truth_as_results_scores_perfectly_and_bad_files_are_refused_naming_the_field() {
    let dir = tempfile::tempdir().expect("dir");
    let results = set_and_its_truth(dir.path());
    let file = dir.path().join("results_nusc.json");
    results.save(&file).expect("written");
    let output = eval(dir.path(), &file);
    assert!(output.status.success(), "{}", text(&output));
    let scores: serde_json::Value = serde_json::from_slice(&output.stdout).expect("json");
    let present = &scores["present_classes"];
    let map = present["mean_ap"].as_f64().expect("mAP");
    assert!((map - 1.0).abs() < 1e-12, "{scores}");
    assert_eq!(present["tp_errors"]["trans_err"].as_f64(), Some(0.0));
    // Officially, the nine classes the set lacks count AP 0: one tenth of the cars' 1.
    let official = scores["official"]["mean_ap"].as_f64().expect("mAP");
    assert!((official - 0.1).abs() < 1e-12, "{official}");

    // A box without its velocity: refused before anything is scored, naming the field.
    let mut raw: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&file).expect("read")).expect("json");
    let (sample, boxes) = raw["results"]
        .as_object_mut()
        .expect("results")
        .iter_mut()
        .find(|(_, boxes)| !boxes.as_array().expect("list").is_empty())
        .expect("a sample with boxes");
    let sample = sample.clone();
    boxes[0].as_object_mut().expect("box").remove("velocity");
    std::fs::write(&file, serde_json::to_vec(&raw).expect("json")).expect("write");
    let refused = eval(dir.path(), &file);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(
        text(&refused).contains(&format!("results.{sample}[0]"))
            && text(&refused).contains("velocity"),
        "{}",
        text(&refused)
    );
    // A negative size, named with its sample and box.
    let mut bad = results.clone();
    bad.results.get_mut(&sample).expect("sample")[0].size[2] = -1.0;
    std::fs::write(&file, serde_json::to_vec(&bad).expect("json")).expect("write");
    let refused = eval(dir.path(), &file);
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(
        text(&refused).contains(&format!("sample {sample}, box 0")),
        "{}",
        text(&refused)
    );
    // Results for other samples than the set's: refused as the devkit refuses them.
    let mut other = results;
    other.results.remove(&sample);
    other.results.insert("elsewhere".into(), Vec::new());
    other.save(&file).expect("written");
    let refused = eval(dir.path(), &file);
    assert!(!refused.status.success());
    assert!(
        text(&refused).contains("same samples"),
        "{}",
        text(&refused)
    );
}
