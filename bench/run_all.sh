#!/usr/bin/env bash
# Every benchmark, one after the other (they must not share the CPU), logs in bench/results/.
#   [FIT_DATA_ROOT=DIR] bash bench/run_all.sh [DEMO_MEDIUM_DIR]
# DEMO_MEDIUM_DIR: a generated medium demo collection (<data_root>/demo/medium) for the HOG channel
# choice and the bf16 recall on real descriptors; generated into /tmp when absent.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
DEMO=${1:-/tmp/photoshape-bench-demo/medium}
mkdir -p bench/results
run() { local name=$1; shift; echo "== $name: $*"; /usr/bin/time -v "$PY" "$@" > "bench/results/$name.log" 2>&1 \
  || { echo "$name failed (see bench/results/$name.log)"; return 1; }; tail -n 40 "bench/results/$name.log"; }
run render bench/render.py
run frozen_render bench/frozen_render.py
run hog_channels bench/hog_channels.py --size medium --demo "$DEMO"
run retrieval bench/retrieval.py
run fine_alignment bench/fine_alignment.py
run classifier bench/classifier.py
run ingest bench/ingest.py
# the fit stage's budgets need a data root that has run to `fit` (e.g. the second world's, or a medium demo's)
if [ -n "${FIT_DATA_ROOT:-}" ]; then run fit bench/fit.py --data-root "$FIT_DATA_ROOT"; fi
