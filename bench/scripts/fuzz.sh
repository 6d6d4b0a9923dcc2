#!/usr/bin/env bash
# Every parser's fuzz test (tests/fuzz.rs) at a long budget: CASES generated and mutated inputs
# per parser (20,000 unless given). The default test run uses a few dozen to a few hundred.
#   bench/scripts/fuzz.sh [CASES]
set -euo pipefail
cd "$(dirname "$0")/../.."
PROPTEST_CASES="${1:-20000}" cargo test --release --test fuzz -- --nocapture
