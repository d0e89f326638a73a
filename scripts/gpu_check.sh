#!/usr/bin/env bash
# The GPU check (benchmarks/gpu_check.py): a dataset with fruit masks, every preset on CUDA past its first box fit and
# an upsampling (fruit head on), ns-eval, ns-render and agrinerf-count on the paper preset's run, its step time against
# tensorf; a table in OUT/gpu_check.md.
#   bash scripts/gpu_check.sh                 on a machine with CUDA (sized for a 10-minute call; not yet timed on a GPU)
#   bash scripts/gpu_check.sh --dry-run       anywhere: parses every command it would run, runs none
#   options: --out DIR (default outputs/gpu-check), --steps N (300), --presets P..., --allow-cpu
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-$( [ -x .venv/bin/python ] && echo .venv/bin/python || echo python3 )}
exec "$PY" benchmarks/gpu_check.py "$@"
