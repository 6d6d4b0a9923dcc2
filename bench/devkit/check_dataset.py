"""Loads a dataset with the official nuScenes devkit, as a user would point it at one, and checks
what the devkit derives from it: every table and reverse index, the categories and attributes,
each box's `num_lidar_pts` against the devkit's own `points_in_box`, box velocities, and the map
and sensor renders (written beside the report).

    python bench/devkit/check_dataset.py DATAROOT VERSION OUT_DIR

Prints one JSON object; exits 1 when the devkit cannot load the set or a count disagrees.
"""
import json
import os
import sys
from collections import Counter

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
from nuscenes.nuscenes import NuScenes  # noqa: E402
from nuscenes.utils.data_classes import LidarPointCloud  # noqa: E402
from nuscenes.utils.geometry_utils import points_in_box  # noqa: E402


def main():
    dataroot, version, out = sys.argv[1], sys.argv[2], sys.argv[3]
    os.makedirs(out, exist_ok=True)
    nusc = NuScenes(version=version, dataroot=dataroot, verbose=False)
    boxes = agree = 0
    velocities = []
    for sample in nusc.sample:
        lidar = sample["data"]["LIDAR_TOP"]
        _, sample_boxes, _ = nusc.get_sample_data(lidar)
        cloud = LidarPointCloud.from_file(nusc.get_sample_data_path(lidar))
        for box, token in zip(sample_boxes, sample["anns"]):
            annotation = nusc.get("sample_annotation", token)
            inside = int(points_in_box(box, cloud.points[:3]).sum())
            boxes += 1
            agree += int(inside == annotation["num_lidar_pts"])
            velocity = nusc.box_velocity(token)
            if not np.any(np.isnan(velocity)):
                velocities.append(float(np.hypot(velocity[0], velocity[1])))
    sample = nusc.sample[len(nusc.sample) // 2]
    nusc.render_sample_data(sample["data"]["LIDAR_TOP"], nsweeps=1, underlay_map=True,
                            out_path=os.path.join(out, "devkit_lidar_boxes.png"))
    nusc.render_sample_data(sample["data"]["CAM_FRONT"],
                            out_path=os.path.join(out, "devkit_cam_front_boxes.png"))
    report = {
        "devkit": "nuscenes-devkit " + __import__("importlib.metadata").metadata.version("nuscenes-devkit"),
        "tables": {name: len(getattr(nusc, name)) for name in nusc.table_names},
        "categories": dict(Counter(a["category_name"] for a in nusc.sample_annotation)),
        "attributes": dict(Counter(nusc.get("attribute", t)["name"]
                                   for a in nusc.sample_annotation for t in a["attribute_tokens"])),
        "visibility": dict(Counter(nusc.get("visibility", a["visibility_token"])["level"]
                                   for a in nusc.sample_annotation)),
        "boxes": boxes,
        "num_lidar_pts_equal_to_points_in_box": agree,
        "boxes_with_velocity": len(velocities),
        "moving_boxes": sum(v > 0.5 for v in velocities),
    }
    print(json.dumps(report, indent=2))
    if boxes == 0 or agree != boxes:
        sys.exit(1)


if __name__ == "__main__":
    main()
