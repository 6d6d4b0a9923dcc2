//! The nuScenes detection metrics on hand-made boxes, against values worked out by hand from
//! the devkit's definitions (`accumulate`, `calc_ap`, `calc_tp`, NDS).

use std::collections::BTreeMap;
use std::f64::consts::FRAC_PI_4;

use bevworld_metrics::detection::{DetectionConfig, SampleTruth, TrueBox, evaluate};
use bevworld_types::Detection;

fn car(sample: &str, x: f64, y: f64, score: f64) -> Detection {
    Detection {
        sample_token: sample.into(),
        translation: [x, y, 0.75],
        size: [2.0, 4.0, 1.5],
        rotation: [1.0, 0.0, 0.0, 0.0],
        velocity: [0.0, 0.0],
        detection_name: "car".into(),
        detection_score: score,
        attribute_name: "vehicle.parked".into(),
    }
}

fn truth(boxes: Vec<Detection>) -> BTreeMap<String, SampleTruth> {
    BTreeMap::from([(
        "s".to_string(),
        SampleTruth {
            ego_translation: [0.0, 0.0, 0.0],
            bike_racks: Vec::new(),
            boxes: boxes
                .into_iter()
                .map(|detection| TrueBox {
                    detection,
                    num_pts: 10,
                })
                .collect(),
        },
    )])
}

fn near(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn perfect_boxes_score_one_everywhere() {
    let boxes = vec![car("s", 10.0, 0.0, -1.0), car("s", 20.0, 5.0, -1.0)];
    let mut predictions = boxes.clone();
    predictions[0].detection_score = 0.9;
    predictions[1].detection_score = 0.8;
    let scores = evaluate(
        &DetectionConfig::for_classes(&["car"]),
        &truth(boxes),
        &BTreeMap::from([("s".to_string(), predictions)]),
    )
    .expect("scores");
    assert!(near(scores.mean_ap, 1.0), "{scores:?}");
    for error in scores.tp_errors.values() {
        assert!(near(*error, 0.0), "{scores:?}");
    }
    assert!(near(scores.nd_score, 1.0));
}

/// Two true cars (A moving at 5 m/s, B parked) and three predictions: one 0.5 m off A, one
/// 5 m from B (a false positive at every threshold), one 1.5 m off B, half its length, turned
/// 90° and with the wrong attribute.
fn worked_example() -> (
    BTreeMap<String, SampleTruth>,
    BTreeMap<String, Vec<Detection>>,
) {
    let mut a = car("s", 10.0, 0.0, -1.0);
    a.velocity = [5.0, 0.0];
    a.attribute_name = "vehicle.moving".into();
    let b = car("s", 20.0, 0.0, -1.0);
    let mut p1 = car("s", 10.3, 0.4, 0.9);
    p1.velocity = [4.0, 0.0];
    p1.attribute_name = "vehicle.moving".into();
    let p2 = car("s", 25.0, 0.0, 0.6);
    let mut p3 = car("s", 20.0, 1.5, 0.3);
    p3.size = [2.0, 2.0, 1.5];
    p3.rotation = [FRAC_PI_4.cos(), 0.0, 0.0, FRAC_PI_4.sin()];
    p3.attribute_name = "vehicle.moving".into();
    (
        truth(vec![a, b]),
        BTreeMap::from([("s".to_string(), vec![p1, p2, p3])]),
    )
}

#[test]
fn a_worked_example_gives_the_ap_tp_errors_and_nds_worked_out_by_hand() {
    let (truth, predictions) = worked_example();
    let scores = evaluate(
        &DetectionConfig::for_classes(&["car"]),
        &truth,
        &predictions,
    )
    .expect("scores");
    let aps = &scores.label_aps["car"];
    // 0.5 m: p1 lies exactly 0.5 m off, which is not closer than 0.5: no match at all.
    assert!(near(aps["0.5"], 0.0), "{aps:?}");
    // 1 m: p1 right, p2 and p3 wrong. Precision 1 below recall 0.5, 1/3 at 0.5, 0 above;
    // the bins from recall 0.11 on, less 0.1, over 0.9.
    let ap_1m = (39.0 * 0.9 + (1.0 / 3.0 - 0.1)) / 90.0 / 0.9;
    assert!(near(aps["1"], ap_1m), "{} against {ap_1m}", aps["1"]);
    // 2 m and 4 m: p3 matches B too. Precision 1, then 0.5 at recall 0.5, rising to 2/3 at 1.
    let rising: f64 = (51..=100)
        .map(|k| 0.5 + (f64::from(k) / 100.0 - 0.5) / 3.0 - 0.1)
        .sum();
    let ap_2m = (39.0 * 0.9 + 0.4 + rising) / 90.0 / 0.9;
    assert!(near(aps["2"], ap_2m), "{} against {ap_2m}", aps["2"]);
    assert!(near(aps["4"], ap_2m));
    let map = (ap_1m + 2.0 * ap_2m) / 4.0;
    assert!(
        near(scores.mean_ap, map),
        "{} against {map}",
        scores.mean_ap
    );
    // The errors at 2 m: with p1's error e1 and the two matches' mean m, the running mean read
    // at each recall's score averages to (51.75 e1 + 38.25 m) / 90 over the bins 11 to 100.
    let expected = |e1: f64, e3: f64| (51.75 * e1 + 38.25 * (e1 + e3) / 2.0) / 90.0;
    let errors = &scores.label_tp_errors["car"];
    let worked = [
        ("trans_err", expected(0.5, 1.5)),
        ("scale_err", expected(0.0, 0.5)),
        ("orient_err", expected(0.0, std::f64::consts::FRAC_PI_2)),
        ("vel_err", expected(1.0, 0.0)),
        ("attr_err", expected(0.0, 1.0)),
    ];
    for (metric, value) in worked {
        assert!(
            near(errors[metric], value),
            "{metric}: {} against {value}",
            errors[metric]
        );
    }
    let tp_sum: f64 = worked.iter().map(|(_, e)| (1.0 - e).max(0.0)).sum();
    let nds = (5.0 * map + tp_sum) / 10.0;
    assert!(
        near(scores.nd_score, nds),
        "{} against {nds}",
        scores.nd_score
    );
}

/// The same boxes under the challenge's config (all ten classes), against the official
/// devkit's figures for them: `bench/scripts/detection-devkit-check.py` with nuscenes-devkit
/// 1.2.0 printed these.
#[test]
fn the_worked_example_under_the_challenge_config_gives_the_official_devkits_figures() {
    let (truth, predictions) = worked_example();
    let scores = evaluate(&DetectionConfig::default(), &truth, &predictions).expect("scores");
    let devkit = [
        ("trans_err", 0.9712500000000001),
        ("scale_err", 0.9106249999999999),
        ("orient_err", 0.9259771354937685),
        ("vel_err", 0.9734375),
        ("attr_err", 0.9015625),
    ];
    for (metric, value) in devkit {
        assert!(
            near(scores.tp_errors[metric], value),
            "{metric}: {}",
            scores.tp_errors[metric]
        );
    }
    assert!(near(scores.label_aps["car"]["1"], 0.43621399176954734));
    assert!(near(scores.label_aps["car"]["2"], 0.7376543209876544));
    assert!(
        near(scores.mean_ap, 0.0477880658436214),
        "{}",
        scores.mean_ap
    );
    assert!(
        near(scores.nd_score, 0.05560881937243385),
        "{}",
        scores.nd_score
    );
}

#[test]
fn boxes_out_of_range_or_without_returns_are_not_scored() {
    // A true car 60 m out (the car range is 50 m) and one with no return: neither counts, and
    // neither does a prediction 60 m out; the one near car scores perfectly.
    let near_car = car("s", 10.0, 0.0, -1.0);
    let mut scores_truth = truth(vec![near_car.clone(), car("s", 60.0, 0.0, -1.0)]);
    scores_truth.get_mut("s").expect("s").boxes.push(TrueBox {
        detection: car("s", 30.0, 0.0, -1.0),
        num_pts: 0,
    });
    let mut hit = near_car;
    hit.detection_score = 0.5;
    let far = car("s", 0.0, 60.0, 0.9);
    let scores = evaluate(
        &DetectionConfig::for_classes(&["car"]),
        &scores_truth,
        &BTreeMap::from([("s".to_string(), vec![hit, far])]),
    )
    .expect("scores");
    assert!(near(scores.mean_ap, 1.0), "{scores:?}");
}

#[test]
fn a_class_without_boxes_scores_zero_ap_and_worst_errors_and_cones_skip_heading() {
    let mut hit = car("s", 10.0, 0.0, 0.5);
    hit.attribute_name = "vehicle.parked".into();
    let scores = evaluate(
        &DetectionConfig::for_classes(&["car", "traffic_cone"]),
        &truth(vec![car("s", 10.0, 0.0, -1.0)]),
        &BTreeMap::from([("s".to_string(), vec![hit])]),
    )
    .expect("scores");
    assert!(near(scores.mean_dist_aps["car"], 1.0));
    assert!(near(scores.mean_dist_aps["traffic_cone"], 0.0));
    assert!(near(scores.mean_ap, 0.5));
    let cone = &scores.label_tp_errors["traffic_cone"];
    assert!(near(cone["trans_err"], 1.0) && near(cone["scale_err"], 1.0));
    for metric in ["orient_err", "vel_err", "attr_err"] {
        assert!(cone[metric].is_nan(), "{metric}");
        // The mean over classes skips the cone's NaN: the car's perfect 0.
        assert!(near(scores.tp_errors[metric], 0.0), "{metric}");
    }
    assert!(near(scores.tp_errors["trans_err"], 0.5));
}

#[test]
fn predictions_for_other_samples_or_too_many_boxes_are_refused() {
    let config = DetectionConfig::for_classes(&["car"]);
    let error = evaluate(
        &config,
        &truth(vec![car("s", 10.0, 0.0, -1.0)]),
        &BTreeMap::from([("t".to_string(), vec![car("t", 10.0, 0.0, 0.5)])]),
    )
    .expect_err("other samples");
    assert!(error.to_string().contains("same samples"), "{error}");
    let error = evaluate(
        &config,
        &truth(vec![car("s", 10.0, 0.0, -1.0)]),
        &BTreeMap::from([("s".to_string(), vec![car("s", 10.0, 0.0, 0.5); 501])]),
    )
    .expect_err("too many");
    assert!(error.to_string().contains("at most 500"), "{error}");
    assert!(
        evaluate(
            &DetectionConfig::for_classes(&[]),
            &truth(vec![]),
            &BTreeMap::new()
        )
        .is_err()
    );
}

/// The synthetic world's keyframes as the devkit's truth: cars with their moving or parked
/// attribute and their returns; the scored truth given back as predictions scores perfectly, and the
/// boxes moved 5 m (past the largest threshold, 4 m) score next to none.
#[test]
fn the_synthetic_truth_scored_against_itself_is_perfect() {
    use bevworld_metrics::detection::sample_truth;
    use bevworld_sensors::synth::{SynthConfig, generate};
    use bevworld_sensors::{Dataset, DatasetFormat, DatasetOptions};

    let dir = tempfile::tempdir().expect("dir");
    let config = SynthConfig {
        seed: 7,
        seconds: 2.0,
        camera_width: 64,
        camera_height: 36,
        ..Default::default()
    };
    generate(dir.path(), &config, |_, _| {}).expect("synthetic set");
    let options = DatasetOptions {
        format: DatasetFormat::Synth,
        skip_images: true,
        ..Default::default()
    };
    let dataset = Dataset::open(dir.path(), &options).expect("opens");
    let mut truth = BTreeMap::new();
    for index in 0..dataset.len() {
        let (sample, sample_truth) =
            sample_truth(&dataset.read(index).expect("frame")).expect("truth");
        truth.insert(sample, sample_truth);
    }
    let boxes: Vec<&TrueBox> = truth.values().flat_map(|t| &t.boxes).collect();
    assert!(boxes.len() >= 10, "{} boxes", boxes.len());
    assert!(boxes.iter().all(|b| b.detection.detection_name == "car"));
    assert!(
        boxes
            .iter()
            .any(|b| b.detection.attribute_name == "vehicle.moving")
    );
    assert!(
        boxes
            .iter()
            .any(|b| b.detection.attribute_name == "vehicle.parked")
    );
    assert!(boxes.iter().any(|b| b.num_pts > 0));
    // The boxes with a return: one without is not scored, so predicting it is a false
    // positive, as in the devkit.
    let given_back = |shift: f64, unseen_too: bool| -> BTreeMap<String, Vec<Detection>> {
        truth
            .iter()
            .map(|(sample, t)| {
                let boxes = t
                    .boxes
                    .iter()
                    .filter(|b| unseen_too || b.num_pts > 0)
                    .map(|b| {
                        let mut d = b.detection.clone();
                        d.detection_score = 0.5;
                        d.translation[0] += shift;
                        d.velocity = d.velocity.map(|v| if v.is_nan() { 0.0 } else { v });
                        d
                    })
                    .collect();
                (sample.clone(), boxes)
            })
            .collect()
    };
    let config = DetectionConfig::for_classes(&["car"]);
    let perfect = evaluate(&config, &truth, &given_back(0.0, false)).expect("scores");
    assert!(near(perfect.mean_ap, 1.0), "{perfect:?}");
    for metric in ["trans_err", "scale_err", "orient_err", "attr_err"] {
        assert!(
            near(perfect.tp_errors[metric], 0.0),
            "{metric}: {perfect:?}"
        );
    }
    // Moved 5 m, a box now and then lands by the parked car next to its own.
    let shifted = evaluate(&config, &truth, &given_back(5.0, false)).expect("scores");
    assert!(shifted.mean_ap < 0.05, "{shifted:?}");
    assert!(
        boxes.iter().any(|b| b.num_pts == 0),
        "no box without a return"
    );
    let unseen = evaluate(&config, &truth, &given_back(0.0, true)).expect("scores");
    assert!(unseen.mean_ap < 1.0 - 1e-6, "{unseen:?}");
}

#[test]
fn a_cycle_parked_in_a_bike_rack_is_not_scored() {
    use bevworld_types::{ObjectBox, Pose};
    let mut bicycle = car("s", 8.0, 3.0, -1.0);
    bicycle.detection_name = "bicycle".into();
    bicycle.size = [0.6, 1.8, 1.2];
    bicycle.attribute_name = "cycle.without_rider".into();
    let mut predicted = bicycle.clone();
    predicted.detection_score = 0.7;
    let rack = ObjectBox {
        instance_token: "rack".into(),
        category: "static_object.bicycle_rack".into(),
        global_from_box: Pose::from_translation(glam::DVec3::new(8.0, 3.0, 0.75)),
        size: [3.0, 6.0, 1.5],
        velocity: None,
        attributes: Vec::new(),
        num_pts: 0,
    };
    let config = DetectionConfig::for_classes(&["bicycle"]);
    let predictions = BTreeMap::from([("s".to_string(), vec![predicted])]);
    let mut with_rack = truth(vec![bicycle]);
    let free = evaluate(&config, &with_rack, &predictions).expect("scores");
    assert!(near(free.mean_ap, 1.0), "{free:?}");
    with_rack.get_mut("s").expect("s").bike_racks.push(rack);
    let parked = evaluate(&config, &with_rack, &predictions).expect("scores");
    // The truth is gone, so the class has nothing to find: AP 0, as the devkit gives it.
    assert!(near(parked.mean_ap, 0.0), "{parked:?}");
}
