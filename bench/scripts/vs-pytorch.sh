#!/usr/bin/env bash
# The side-by-side page, bench/results/vs-pytorch.{md,json}: our tiny tokenizer and our PyTorch
# reference of it (bench/pytorch/tokenizer.py), on the same CPU, weights and inputs, back to back.
#   bench/scripts/vs-pytorch.sh
# Three rounds, alternating (a 2-core VM's speed drifts from minute to minute), each of:
# 1. ours: dumps the weights (safetensors), inputs and outputs to out/vs-pytorch, times each stage
#    on 1 and 2 threads;
# 2. the reference: checks its outputs against ours, then times eager PyTorch on 1 and 2 threads
#    and torch.compile on 2 (compiling takes about a minute the first time);
# then this machine's figures (bench/results/vs-pytorch-<kind>.json, each the median of the
# rounds) and the page, one section per kind of machine measured.
# PyTorch is optional: set BEVWORLD_PYTHON to a Python with torch, numpy and safetensors, or let
# this script use $HOME/.cache/bevworld/torch-venv, made once with
#   python3 -m venv ~/.cache/bevworld/torch-venv &&
#   ~/.cache/bevworld/torch-venv/bin/pip install torch numpy safetensors
# Without it the page holds our half and says that torch was missing.
# PyTorch's allocator: glibc's malloc makes its gather-heavy stages slower here, so when Debian's
# libmimalloc2.0 is installed it is preloaded (ours uses mimalloc too), and the page says which.
set -euo pipefail
cd "$(dirname "$0")/../.."
DIR=out/vs-pytorch
PYTHON="${BEVWORLD_PYTHON:-$HOME/.cache/bevworld/torch-venv/bin/python}"
ROUNDS="${ROUNDS:-3}"
rm -f "$DIR"/ours*.json "$DIR"/torch*.json
cargo build --release -p bevworld-bench --bin vs_pytorch
# The CPU, its vector instructions and the kernels they select: the page names them per machine.
cargo run --release --bin bevworld -- device --size 512
HAVE_TORCH=0
if [ -x "$PYTHON" ] && "$PYTHON" -c "import torch, numpy, safetensors" 2>/dev/null; then
    HAVE_TORCH=1
else
    echo "PyTorch not found at $PYTHON (torch, numpy and safetensors): only our half runs." >&2
    echo "Install: python3 -m venv ~/.cache/bevworld/torch-venv && ~/.cache/bevworld/torch-venv/bin/pip install torch numpy safetensors" >&2
fi
MIMALLOC=/usr/lib/x86_64-linux-gnu/libmimalloc.so.2
for round in $(seq 1 "$ROUNDS"); do
    cargo run --release -p bevworld-bench --bin vs_pytorch -- dump "$DIR"
    mv "$DIR/ours.json" "$DIR/ours-$round.json"
    if [ "$HAVE_TORCH" = 1 ]; then
        if [ -e "$MIMALLOC" ]; then
            LD_PRELOAD="$MIMALLOC" BEVWORLD_TORCH_ALLOCATOR="mimalloc 2.0 (LD_PRELOAD)" \
                "$PYTHON" bench/pytorch/tokenizer.py "$DIR"
        else
            BEVWORLD_TORCH_ALLOCATOR="glibc malloc, defaults (libmimalloc2.0 not installed)" \
                "$PYTHON" bench/pytorch/tokenizer.py "$DIR"
        fi
        mv "$DIR/torch.json" "$DIR/torch-$round.json"
    fi
done
cargo run --release -p bevworld-bench --bin vs_pytorch -- report "$DIR"
