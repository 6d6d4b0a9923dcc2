#!/usr/bin/env python3
"""The worked example of nodes/metrics/tests/detection.rs, scored by the official nuScenes
devkit (pip install nuscenes-devkit): its accumulate, calc_ap and calc_tp and its
DetectionMetrics, on the same boxes. Prints one JSON object with the figures our test
(`the_worked_example_under_the_challenge_config_gives_the_official_devkits_figures`) asserts.

    python3 bench/scripts/detection-devkit-check.py > bench/results/detection-devkit-check.json
"""
import json
import math
from importlib.metadata import version

import numpy as np
from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.common.utils import center_distance
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.detection.constants import TP_METRICS
from nuscenes.eval.detection.data_classes import (DetectionBox, DetectionConfig,
                                                   DetectionMetricDataList, DetectionMetrics)


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
# The challenge's config (detection_cvpr_2019): the devkit scores all ten classes.
ranges = {"car": 50, "truck": 50, "bus": 50, "trailer": 50, "construction_vehicle": 50,
          "pedestrian": 40, "motorcycle": 40, "bicycle": 40, "traffic_cone": 30, "barrier": 30}
cfg = DetectionConfig(class_range=ranges, dist_fcn="center_distance",
                      dist_ths=[0.5, 1.0, 2.0, 4.0], dist_th_tp=2.0, min_recall=0.1,
                      min_precision=0.1, max_boxes_per_sample=500, mean_ap_weight=5)
# DetectionEval.evaluate's loop, without the dataset it loads the boxes from.
data = DetectionMetricDataList()
for name in cfg.class_names:
    for th in cfg.dist_ths:
        data.set(name, th, accumulate(gt, pred, name, center_distance, th))
metrics = DetectionMetrics(cfg)
for name in cfg.class_names:
    for th in cfg.dist_ths:
        metrics.add_label_ap(name, th, calc_ap(data[(name, th)], cfg.min_recall, cfg.min_precision))
    for metric in TP_METRICS:
        if name == "traffic_cone" and metric in ["attr_err", "vel_err", "orient_err"]:
            tp = np.nan
        elif name == "barrier" and metric in ["attr_err", "vel_err"]:
            tp = np.nan
        else:
            tp = calc_tp(data[(name, cfg.dist_th_tp)], cfg.min_recall, metric)
        metrics.add_label_tp(name, metric, tp)
summary = metrics.serialize()
print(json.dumps({
    "car_aps": summary["label_aps"]["car"],
    "car_tp_errors": summary["label_tp_errors"]["car"],
    "mean_ap": summary["mean_ap"],
    "tp_errors": summary["tp_errors"],
    "nd_score": summary["nd_score"],
    "devkit": "nuscenes-devkit " + version("nuscenes-devkit"),
}, indent=1, default=float))
