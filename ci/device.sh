#!/usr/bin/env bash
# On a lent GPU machine (no network, Python 3.12, no drjit/mitsuba): install the carried
# wheels from .whl/ (made by ../shared/tools/device-wheels.sh plus the test/report extras)
# into a venv that sees the machine's own numpy/pillow, then run what is asked:
#   bash ci/device.sh tests         the test suite's CUDA cases
#   bash ci/device.sh bench [ARGS]  whitted bench --backend cuda ARGS (results to $OUT)
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
python3 -m venv --system-site-packages /tmp/v >/dev/null
/tmp/v/bin/python -m pip install -q --no-index --find-links .whl \
  drjit mitsuba pytest openexr imageio flip-evaluator 2>&1 | grep -v -i warning
export PATH=/tmp/v/bin:$PATH PYTHONPATH=$PWD
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
python -c "import drjit as dr, mitsuba as mi; print('drjit', dr.__version__, 'mitsuba', mi.__version__, 'cuda', dr.has_backend(dr.JitBackend.CUDA))"
what=${1:-tests}; shift || true
case "$what" in
  tests) python -m pytest -q -x -k cuda -p no:cacheprovider "$@" tests/ ;;
  bench) python -m whitted bench --backend cuda --out "${OUT:-results}" "$@" ;;
esac
