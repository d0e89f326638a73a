#!/usr/bin/env bash
# Install agrinerf-ns and everything it needs into ./.venv (created if absent), from nothing but Python 3.11 and pip.
#   bash scripts/install.sh            the plugin, as a user gets it (non-editable)
#   bash scripts/install.sh --dev      plus pytest, ruff, mypy, beartype, the [detect] and [ray] extras (what the tests need)
#   bash scripts/install.sh --editable install the plugin editable (for development); combine with --dev
# As root on Debian/Ubuntu it also apt-get installs the system packages pip cannot (scripts/install_system.sh).
# Environment: TORCH_SPEC overrides the torch/torchvision pair (default: the pair tested here, see README).
set -euo pipefail
cd "$(dirname "$0")/.."
DEV=0; EDITABLE=0
for arg in "$@"; do
  case "$arg" in
    --dev) DEV=1 ;;
    --editable) EDITABLE=1 ;;
    *) echo "install.sh: unknown option '$arg' (use --dev, --editable)" >&2; exit 2 ;;
  esac
done
PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
. .venv/bin/activate
python -m pip install --quiet --upgrade pip
# 1. torch first, on its own: the pair tested here (on x86_64 pip takes it from the local wheel cache when present).
python -m pip install --quiet ${TORCH_SPEC:-torch==2.14.1 torchvision==0.29.1}
# 2. the plugin with Nerfstudio and the rest of its dependencies (imageio-ffmpeg among them: the ffmpeg of ns-render
#    videos, which agrinerf_ns.compat puts on PATH for ns-* commands when PATH has none).
TARGET="."
[ "$DEV" = 1 ] && TARGET=".[dev,ray]"  # [ray]: the tests of agrinerf-bench --ray and agrinerf-survey --ray
if [ "$EDITABLE" = 1 ]; then python -m pip install --quiet -e "$TARGET"; else python -m pip install --quiet "$TARGET"; fi
# 3. Nerfstudio pins opencv-python-headless; opencv-contrib-python-headless ships the same cv2 module plus the contrib
#    modules. Whichever is written last owns cv2, so write the contrib wheel last, explicitly.
python -m pip install --quiet --force-reinstall --no-deps "opencv-contrib-python-headless==4.10.0.84"
# 4. optional detection extra (Ultralytics, AGPL-3.0), installed without its opencv-python requirement.
if [ "$DEV" = 1 ]; then bash scripts/install_detect.sh; fi
# optional FLIR radiometric JPEG reader (flyr, EUPL-1.2, pure Python) for the tests of agrinerf_ns/process/flir.py
if [ "$DEV" = 1 ]; then python -m pip install --quiet "flyr>=5.1"; fi
# 5. system packages pip cannot install: open3d's libusb, libEGL, libGL and pymeshlab's
#    libOpenGL (ns-export) and, with --dev, Chromium (the viewer test).
#    install_system.sh installs them as root on Debian/Ubuntu (apt-get), else says what to run; system_deps then
#    checks what the ns-* commands load (open3d, ffmpeg). Neither stops the install: only the commands named need them.
SYSTEM_OK=1; SYSTEM_FLAG=""
[ "$DEV" = 1 ] && SYSTEM_FLAG="--dev"
bash scripts/install_system.sh $SYSTEM_FLAG || SYSTEM_OK=0
python -m agrinerf_ns.system_deps || SYSTEM_OK=0
[ "$SYSTEM_OK" = 1 ] || echo "install.sh: installed; the commands named above need what is missing" >&2
python -c "import cv2; cv2.ximgproc; import agrinerf_ns, nerfstudio; print('agrinerf-ns', agrinerf_ns.__version__, 'installed; cv2', cv2.__version__)"
