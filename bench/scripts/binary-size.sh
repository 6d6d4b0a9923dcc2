#!/usr/bin/env bash
# What a user installs: the size of the `bevworld` binary as `cargo build --release` makes it
# (with line tables, for profilers and backtraces) and as `cargo build --profile dist` makes it
# (without them), and how much of it is code. Writes bench/results/binary-size.{json,md}.
#   bench/scripts/binary-size.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
cargo build --release --bin bevworld
cargo build --profile dist --bin bevworld
TARGET="${CARGO_TARGET_DIR:-target}"
release=$(stat -c %s "$TARGET/release/bevworld")
dist=$(stat -c %s "$TARGET/dist/bevworld")
text=$(size -A "$TARGET/dist/bevworld" | awk '$1 == ".text" {print $2}')
cat > bench/results/binary-size.json <<JSON
{
  "release_bytes": $release,
  "dist_bytes": $dist,
  "dist_text_bytes": $text,
  "backends": "flex (CPU) and wgpu (GPU) compiled in; cuda only with --features cuda"
}
JSON
python3 - <<'PY'
import json
d = json.load(open("bench/results/binary-size.json"))
mb = lambda b: f"{b / 1e6:.1f} MB"
open("bench/results/binary-size.md", "w").write(
    "# The size of the binary\n\nReproduce: `bench/scripts/binary-size.sh`\n\n"
    "| build | size | of which code (.text) |\n|---|---|---|\n"
    f"| `cargo build --release` (line tables, for profilers) | {mb(d['release_bytes'])} | |\n"
    f"| `cargo build --profile dist` (what a user installs) | {mb(d['dist_bytes'])} | {mb(d['dist_text_bytes'])} |\n\n"
    f"Both hold {d['backends']}; the code is mostly burn's kernels for both backends.\n")
PY
cat bench/results/binary-size.md
