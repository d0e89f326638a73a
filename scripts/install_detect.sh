#!/usr/bin/env bash
# Install the optional detection extra (Ultralytics YOLOv8, AGPL-3.0) into the active Python environment
# WITHOUT letting it replace the headless contrib OpenCV that Nerfstudio and agrinerf-ns use.
#
# Ultralytics requires `opencv-python`, a third distribution of the same `cv2` module; installing it would
# overwrite cv2 from opencv-contrib-python-headless (losing cv2.ximgproc). So: Ultralytics itself with
# --no-deps, then its remaining runtime requirements (from its wheel metadata, opencv-python left out),
# with torch/torchvision/numpy/OpenCV/nerfstudio pinned to what is already installed.
# Idempotent: safe to run again. Usage: scripts/install_detect.sh   (inside the activated venv)
set -euo pipefail

ULTRALYTICS_VERSION="${ULTRALYTICS_VERSION:-8.4.190}"
PY="${PYTHON:-python}"

if "$PY" -m pip show opencv-python >/dev/null 2>&1; then
    echo "error: opencv-python is installed beside opencv-contrib-python-headless; both own cv2." >&2
    echo "repair: $PY -m pip uninstall -y opencv-python && $PY -m pip install --force-reinstall --no-deps opencv-contrib-python-headless==4.10.0.84" >&2
    exit 1
fi

# Pin what is already there so no requirement below can upgrade or replace it.
constraints="$(mktemp)"
trap 'rm -f "$constraints"' EXIT
"$PY" -m pip freeze --exclude-editable 2>/dev/null \
    | grep -iE '^(torch|torchvision|numpy|opencv-[a-z-]+|nerfstudio)==' > "$constraints" || true

# 1. Ultralytics alone.
"$PY" -m pip install --no-deps "ultralytics==${ULTRALYTICS_VERSION}"

# 2. Its runtime requirements except opencv-python (Requires-Dist of ultralytics 8.4.x, no extras),
#    plus the scoring cross-check backends (torchmetrics' mAP uses pycocotools).
"$PY" -m pip install -c "$constraints" \
    "numpy>=1.23.0" "matplotlib>=3.3.0" "pillow>=7.1.2" "pyyaml>=5.3.1" "requests>=2.23.0" \
    "torch>=1.8.0" "torchvision>=0.9.0" "psutil>=5.8.0" "polars>=0.20.0" "nvidia-ml-py>=12.0.0" \
    "ultralytics-thop>=2.2.3" "ultralytics-platform>=0.1.45; python_version >= '3.11'" \
    "torchmetrics>=1.0" "pycocotools>=2.0.6"

# 3. Verify: the contrib cv2 (with ximgproc) survived, Ultralytics imports, no third cv2 distribution.
if "$PY" -m pip show opencv-python >/dev/null 2>&1; then
    echo "error: opencv-python was pulled in; see the repair line above." >&2
    exit 1
fi
"$PY" -c "import cv2; cv2.ximgproc; import ultralytics; print('cv2', cv2.__version__, '+ ximgproc; ultralytics', ultralytics.__version__)"
