#!/usr/bin/env python3
"""`bevworld eval detector` against the official nuScenes devkit on a whole synthetic set.

Makes a synthetic set, writes a results file of noisy detections (the truth moved, resized,
turned and re-scored by a seeded generator, some boxes dropped, false ones added), scores it
with the devkit (its loaders, filters, accumulate, calc_ap, calc_tp and DetectionMetrics: the
body of DetectionEval.evaluate without the official split, which names nuScenes scenes) and
with `bevworld eval detector --json`, and prints both and their largest difference:

    python3 bench/scripts/detection-devkit-pipeline.py > bench/results/detection-devkit-pipeline.json

Needs `pip install nuscenes-devkit` and a release build (`BIN`, default target/release/bevworld,
or the CI cache's).
"""
import json
import math
import os
import subprocess
import sys
import tempfile
from importlib.metadata import version

import numpy as np
from pyquaternion import Quaternion
from nuscenes import NuScenes
from nuscenes.eval.detection.constants import TP_METRICS

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "devkit"))
from detection_metrics import devkit_scores, truth  # noqa: E402

SEED, SCENES, SECONDS, PEDESTRIANS, CYCLISTS = 9800, 2, 6, 20, 6
# A wrong attribute is the other of its class's pair.
OTHER = {"vehicle.moving": "vehicle.parked", "vehicle.parked": "vehicle.moving",
         "pedestrian.moving": "pedestrian.standing", "pedestrian.standing": "pedestrian.moving",
         "cycle.with_rider": "cycle.without_rider", "": ""}


def binary():
    for candidate in [os.environ.get("BIN"), "target/release/bevworld",
                      os.path.expanduser("~/.cache/bevworld/target/release/bevworld")]:
        if candidate and os.path.isfile(candidate):
            return candidate
    sys.exit("no bevworld binary: cargo build --release, or set BIN")


def noisy(gt, rng):
    """Detections a fair detector might make: most boxes found, moved and resized a little."""
    results = {}
    for token in gt.sample_tokens:
        rows = []
        for box in gt[token]:
            if rng.random() < 0.15:
                continue
            yaw = Quaternion(box.rotation).yaw_pitch_roll[0] + rng.normal(0.0, 0.3)
            rotation = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
            velocity = [0.0 if math.isnan(v) else v + rng.normal(0.0, 0.5) for v in box.velocity]
            rows.append({
                "sample_token": token,
                "translation": [box.translation[0] + rng.normal(0.0, 0.6),
                                box.translation[1] + rng.normal(0.0, 0.6), box.translation[2]],
                "size": [s * float(np.exp(rng.normal(0.0, 0.1))) for s in box.size],
                "rotation": rotation, "velocity": velocity,
                "detection_name": box.detection_name,
                "detection_score": float(rng.uniform(0.05, 1.0)),
                "attribute_name": box.attribute_name if rng.random() < 0.8 else
                OTHER[box.attribute_name],
            })
        for _ in range(int(rng.integers(0, 4))):
            rows.append({
                "sample_token": token,
                "translation": [float(rng.uniform(-40, 40)), float(rng.uniform(-40, 40)), 0.8],
                "size": [1.9, 4.5, 1.6], "rotation": [1.0, 0.0, 0.0, 0.0], "velocity": [0.0, 0.0],
                "detection_name": "car", "detection_score": float(rng.uniform(0.0, 0.5)),
                "attribute_name": "vehicle.parked",
            })
        results[token] = rows
    return results


def main():
    bin_ = binary()
    with tempfile.TemporaryDirectory() as work:
        data = os.path.join(work, "synth")
        subprocess.run([bin_, "synth", "--out", data, "--seed", str(SEED), "--scenes", str(SCENES),
                        "--seconds", str(SECONDS), "--camera-size", "64x36",
                        "--pedestrians", str(PEDESTRIANS), "--cyclists", str(CYCLISTS)],
                       check=True, capture_output=True)
        nusc = NuScenes(version="v1.0-synth", dataroot=data, verbose=False)
        gt = truth(nusc)
        results = noisy(gt, np.random.default_rng(SEED))
        path = os.path.join(work, "results_nusc.json")
        with open(path, "w") as f:
            json.dump({"meta": {"use_camera": False, "use_lidar": True, "use_radar": False,
                                "use_map": False, "use_external": False}, "results": results}, f)
        devkit = devkit_scores(nusc, gt, results)
        ours = json.loads(subprocess.run([bin_, "eval", "detector", "--data", data, "--results", path,
                                          "--json"], check=True, capture_output=True, text=True).stdout)
    official = ours["official"]
    pairs = [(devkit["mean_ap"], official["mean_ap"]), (devkit["nd_score"], official["nd_score"])]
    pairs += [(devkit["tp_errors"][m], official["tp_errors"][m]) for m in TP_METRICS]
    for name in ["car", "pedestrian", "bicycle"]:
        pairs += [(devkit["label_aps"][name][th], official["label_aps"][name][k])
                  for th, k in [(0.5, "0.5"), (1.0, "1"), (2.0, "2"), (4.0, "4")]]
        pairs += [(devkit["label_tp_errors"][name][m], official["label_tp_errors"][name][m])
                  for m in TP_METRICS]
    print(json.dumps({
        "devkit": "nuscenes-devkit " + version("nuscenes-devkit"),
        "set": {"seed": SEED, "scenes": SCENES, "seconds": SECONDS, "pedestrians": PEDESTRIANS,
                "cyclists": CYCLISTS, "samples": ours["samples"]},
        "classes": {name: {"devkit_map": float(np.mean(list(devkit["label_aps"][name].values()))),
                           "our_map": official["mean_dist_aps"][name]}
                    for name in ["car", "pedestrian", "bicycle"]},
        "devkit_scores": {"mean_ap": devkit["mean_ap"], "nd_score": devkit["nd_score"],
                          "tp_errors": devkit["tp_errors"],
                          "car_aps": {str(k): v for k, v in devkit["label_aps"]["car"].items()},
                          "car_tp_errors": devkit["label_tp_errors"]["car"]},
        "our_scores": {"mean_ap": official["mean_ap"], "nd_score": official["nd_score"],
                       "tp_errors": official["tp_errors"], "car_aps": official["label_aps"]["car"],
                       "car_tp_errors": official["label_tp_errors"]["car"]},
        "largest_difference": max(abs(a - b) for a, b in pairs),
    }, indent=1))


if __name__ == "__main__":
    main()
