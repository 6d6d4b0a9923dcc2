#!/usr/bin/env python3
"""A trained detector's test detections scored by the official nuScenes devkit and by
`bevworld eval detector`, side by side: the devkit loads the synthetic test set as nuScenes,
takes its ground truth and filters, and scores the very `results_nusc.json` that
`bevworld train detector` wrote.

    python3 bench/scripts/downstream-devkit.py runs/downstream/frozen-latent-2f out/synth-det-test \\
        > bench/results/downstream-devkit.json

Needs `pip install nuscenes-devkit` and a release build (`BIN`, default target/release/bevworld,
or the CI cache's).
"""
import json
import os
import subprocess
import sys
from importlib.metadata import version

from nuscenes import NuScenes
from nuscenes.eval.detection.constants import TP_METRICS

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "devkit"))
from detection_metrics import devkit_scores, truth  # noqa: E402


def binary():
    for candidate in [os.environ.get("BIN"), "target/release/bevworld",
                      os.path.expanduser("~/.cache/bevworld/target/release/bevworld")]:
        if candidate and os.path.isfile(candidate):
            return candidate
    sys.exit("no bevworld binary: cargo build --release, or set BIN")


def main():
    if len(sys.argv) != 3:
        sys.exit("usage: downstream-devkit.py RUN DATA")
    run, data = sys.argv[1], sys.argv[2]
    path = os.path.join(run, "test", "results_nusc.json")
    with open(path) as f:
        results = json.load(f)["results"]
    nusc = NuScenes(version="v1.0-synth", dataroot=data, verbose=False)
    devkit = devkit_scores(nusc, truth(nusc), results)
    ours = json.loads(subprocess.run([binary(), "eval", "detector", "--data", data, "--results", path,
                                      "--json"], check=True, capture_output=True, text=True).stdout)
    official = ours["official"]
    pairs = [(devkit["mean_ap"], official["mean_ap"]), (devkit["nd_score"], official["nd_score"])]
    pairs += [(devkit["tp_errors"][m], official["tp_errors"][m]) for m in TP_METRICS]
    for name in ["car", "pedestrian", "bicycle"]:
        pairs += [(devkit["label_aps"][name][th], official["label_aps"][name][k])
                  for th, k in [(0.5, "0.5"), (1.0, "1"), (2.0, "2"), (4.0, "4")]]
    print(json.dumps({
        "devkit": "nuscenes-devkit " + version("nuscenes-devkit"),
        "run": os.path.basename(os.path.normpath(run)),
        "samples": ours["samples"],
        "devkit_scores": {"mean_ap": devkit["mean_ap"], "nd_score": devkit["nd_score"],
                          "tp_errors": devkit["tp_errors"]},
        "our_scores": {"mean_ap": official["mean_ap"], "nd_score": official["nd_score"],
                       "tp_errors": official["tp_errors"]},
        "largest_difference": max(abs(a - b) for a, b in pairs),
    }, indent=1))


if __name__ == "__main__":
    main()
