#!/usr/bin/env bash
# Points the official nuScenes devkit at what `bevworld synth` writes, as a user would: it must
# load the set and agree with its boxes. Writes bench/results/nuscenes-devkit.{json,md} and the
# devkit's own renders.
#   bench/scripts/nuscenes-devkit.sh
# The devkit (nuscenes-devkit 1.2.0, from PyPI) goes into $HOME/.cache/bevworld/devkit-venv
# the first time, or set BEVWORLD_DEVKIT_PYTHON to a Python that has it.
set -euo pipefail
cd "$(dirname "$0")/../.."
PYTHON="${BEVWORLD_DEVKIT_PYTHON:-$HOME/.cache/bevworld/devkit-venv/bin/python}"
if ! [ -x "$PYTHON" ] || ! "$PYTHON" -c "import nuscenes" 2>/dev/null; then
    python3 -m venv "$HOME/.cache/bevworld/devkit-venv"
    PYTHON="$HOME/.cache/bevworld/devkit-venv/bin/python"
    "$PYTHON" -m pip install -q nuscenes-devkit==1.2.0
fi
DATA=out/synth-devkit
rm -rf "$DATA"
cargo run --release -- synth --out "$DATA" --seed 0 --scenes 2 --seconds 4 --pedestrians 20 --cyclists 6
"$PYTHON" bench/devkit/check_dataset.py "$DATA" v1.0-synth bench/results | tee bench/results/nuscenes-devkit.json
python3 - <<'PY'
import json
r = json.load(open("bench/results/nuscenes-devkit.json"))
rows = "\n".join(f"| `{t}` | {n} |" for t, n in r["tables"].items())
open("bench/results/nuscenes-devkit.md", "w").write(
    "# The synthetic world in the official nuScenes devkit\n\n"
    "Reproduce: `bench/scripts/nuscenes-devkit.sh` (two scenes of 4 s, seeds 0 and 1, with 20 "
    "pedestrians and 6 cyclists each).\n\n"
    f"{r['devkit']} loads the set (`NuScenes(version='v1.0-synth', dataroot=...)`), builds its "
    "reverse indices and renders it. Its `points_in_box` finds in "
    f"{r['num_lidar_pts_equal_to_points_in_box']} of {r['boxes']} boxes exactly the "
    "`num_lidar_pts` the set records; its `box_velocity` gives "
    f"{r['boxes_with_velocity']} boxes a velocity, {r['moving_boxes']} of them over 0.5 m/s.\n\n"
    f"Categories: {r['categories']}. Attributes: {r['attributes']}. Visibility: {r['visibility']}.\n\n"
    "| table | records |\n|---|---|\n" + rows + "\n\n"
    "The tables follow the nuScenes schema since 2026-12-06: the devkit's 23 categories, 8 "
    "attributes and 4 visibility levels as tables their tokens resolve in; a visibility graded "
    "per box (the share of points on its faces turned to the rig that the LiDAR's eye reaches); "
    "a `map` record naming every log, with a 0.1 m semantic-prior mask of the drivable area; "
    "boxes grown 2 cm beyond the body on every side, so that the returns on its faces lie in "
    "it. Sets written before hold the same sensor files and other tables.\n\n"
    "![the devkit's LiDAR render, boxes over the map](devkit_lidar_boxes.png)\n\n"
    "![the devkit's CAM_FRONT render with the boxes](devkit_cam_front_boxes.png)\n")
PY
cat bench/results/nuscenes-devkit.md
