"""The body of the nuScenes devkit's DetectionEval.evaluate on boxes already loaded and
filtered: its accumulate, calc_ap and calc_tp per class and threshold, into DetectionMetrics;
and, for a whole dataset, its ground truth (`truth`, load_gt for every sample) and its
loaders' filters before the scoring (`devkit_scores`). The official split names nuScenes
scenes, so the detection cross-checks call these instead of DetectionEval itself. Shared by
bench/scripts/detection-devkit-check.py, detection-devkit-pipeline.py and
downstream-devkit.py."""
import numpy as np
from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.common.loaders import add_center_dist, filter_eval_boxes
from nuscenes.eval.common.utils import center_distance
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.detection.constants import TP_METRICS
from nuscenes.eval.detection.config import config_factory
from nuscenes.eval.detection.data_classes import DetectionBox, DetectionMetricDataList, DetectionMetrics
from nuscenes.eval.detection.utils import category_to_detection_name


def score(gt, pred, cfg):
    """DetectionMetrics.serialize() of `pred` against `gt` (EvalBoxes) under `cfg`."""
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
    return metrics.serialize()


def truth(nusc):
    """load_gt, for every sample of the set."""
    boxes = EvalBoxes()
    for sample in nusc.sample:
        rows = []
        for token in sample["anns"]:
            ann = nusc.get("sample_annotation", token)
            name = category_to_detection_name(ann["category_name"])
            if name is None:
                continue
            attrs = ann["attribute_tokens"]
            attribute = nusc.get("attribute", attrs[0])["name"] if len(attrs) == 1 else ""
            rows.append(DetectionBox(
                sample_token=sample["token"], translation=ann["translation"], size=ann["size"],
                rotation=ann["rotation"], velocity=nusc.box_velocity(token)[:2],
                num_pts=ann["num_lidar_pts"] + ann["num_radar_pts"], detection_name=name,
                detection_score=-1.0, attribute_name=attribute))
        boxes.add_boxes(sample["token"], rows)
    return boxes


def devkit_scores(nusc, gt, results):
    """DetectionEval.evaluate on these boxes: the devkit's loaders' filters, then its scoring."""
    cfg = config_factory("detection_cvpr_2019")
    pred = EvalBoxes.deserialize(results, DetectionBox)
    gt, pred = add_center_dist(nusc, gt), add_center_dist(nusc, pred)
    gt = filter_eval_boxes(nusc, gt, cfg.class_range)
    pred = filter_eval_boxes(nusc, pred, cfg.class_range)
    return score(gt, pred, cfg)
