#!/usr/bin/env python3
"""What a detector's motion outputs say of the cars it finds (bench/scripts/agents.sh): of its
car detections scored at least MIN_SCORE in a `detect.yaml` run, how many have a velocity above
1 m/s, and how many have a most probable trajectory mode that moves them more than 1 m within
1 s (two steps of 0.5 s). The world model's scenes hold about one moving car per keyframe
beside a dozen parked ones.

  agents-detector-motion.py OUT_DIR MIN_SCORE > summary.json
"""
import json
import math
import sys


def main() -> None:
    out, min_score = sys.argv[1], float(sys.argv[2])
    results = json.load(open(f"{out}/results_nusc.json"))["results"]
    trajectories = json.load(open(f"{out}/trajectories.json"))["samples"]
    cars = fast = moving_mode = 0
    for sample, detections in results.items():
        agents = trajectories.get(sample, [])
        if len(agents) != len(detections):
            sys.exit(f"{out}: {sample} has {len(detections)} boxes and {len(agents)} trajectories")
        for box, agent in zip(detections, agents):
            if box["detection_name"] != "car" or box["detection_score"] < min_score:
                continue
            cars += 1
            fast += math.hypot(*box["velocity"]) > 1.0
            start = box["translation"][:2]
            positions = agent["modes"][0]["positions"]
            moving_mode += len(positions) >= 2 and math.dist(start, positions[1]) > 1.0
    json.dump(
        {
            "keyframes": len(results),
            "min_score": min_score,
            "cars": cars,
            "velocity_above_1_mps": fast,
            "top_mode_moves_1m_in_1s": moving_mode,
        },
        sys.stdout,
        indent=1,
    )
    print()


if __name__ == "__main__":
    main()
