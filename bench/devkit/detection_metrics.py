"""The body of the nuScenes devkit's DetectionEval.evaluate on boxes already loaded and
filtered: its accumulate, calc_ap and calc_tp per class and threshold, into DetectionMetrics.
The official split names nuScenes scenes, so the detection cross-checks call this instead of
DetectionEval itself. Shared by bench/scripts/detection-devkit-check.py and
bench/scripts/detection-devkit-pipeline.py."""
import numpy as np
from nuscenes.eval.common.utils import center_distance
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.detection.constants import TP_METRICS
from nuscenes.eval.detection.data_classes import DetectionMetricDataList, DetectionMetrics


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
