#!/usr/bin/env python3
"""The worked example of nodes/metrics/tests/detection.rs, scored by the official nuScenes
devkit (pip install nuscenes-devkit): its accumulate, calc_ap and calc_tp and its
DetectionMetrics, on the same boxes. Prints one JSON object with the figures our test
(`the_worked_example_under_the_challenge_config_gives_the_official_devkits_figures`) asserts.

    python3 bench/scripts/detection-devkit-check.py > bench/results/detection-devkit-check.json
"""
import json
import math
import os
import sys
from importlib.metadata import version

from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.detection.config import config_factory
from nuscenes.eval.detection.data_classes import DetectionBox

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "devkit"))
from detection_metrics import score  # noqa: E402


def car(x, y, score, velocity=(0.0, 0.0), attribute="vehicle.parked", size=(2.0, 4.0, 1.5),
        yaw=0.0, num_pts=-1):
    return DetectionBox(sample_token="s", translation=(x, y, 0.75), size=size,
                        rotation=(math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
                        velocity=velocity, ego_translation=(x, y, 0.75), num_pts=num_pts,
                        detection_name="car", detection_score=score, attribute_name=attribute)


gt = EvalBoxes()
gt.add_boxes("s", [car(10.0, 0.0, -1.0, velocity=(5.0, 0.0), attribute="vehicle.moving", num_pts=10),
                   car(20.0, 0.0, -1.0, num_pts=10)])
pred = EvalBoxes()
pred.add_boxes("s", [car(10.3, 0.4, 0.9, velocity=(4.0, 0.0), attribute="vehicle.moving"),
                     car(25.0, 0.0, 0.6),
                     car(20.0, 1.5, 0.3, size=(2.0, 2.0, 1.5), yaw=math.pi / 2,
                         attribute="vehicle.moving")])
# The challenge's config: the devkit scores all ten classes.
summary = score(gt, pred, config_factory("detection_cvpr_2019"))
print(json.dumps({
    "car_aps": summary["label_aps"]["car"],
    "car_tp_errors": summary["label_tp_errors"]["car"],
    "mean_ap": summary["mean_ap"],
    "tp_errors": summary["tp_errors"],
    "nd_score": summary["nd_score"],
    "devkit": "nuscenes-devkit " + version("nuscenes-devkit"),
}, indent=1, default=float))
