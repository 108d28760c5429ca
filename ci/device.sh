#!/usr/bin/env bash
# On a lent GPU machine (no network, Python 3.12, no drjit/mitsuba): install the carried
# wheels from .whl/ (made by ../shared/tools/device-wheels.sh plus the test/report extras)
# into a venv that sees the machine's own numpy/pillow, then run what is asked:
#   bash ci/device.sh tests         the test suite's CUDA cases
#   bash ci/device.sh run ARGS      whitted ARGS (any subcommand)
#   bash ci/device.sh py ARGS       python ARGS
#   bash ci/device.sh bench [ARGS]  whitted bench --backend cuda ARGS (results to $OUT)
#   bash ci/device.sh run ARGS      whitted ARGS
# The device tool carries the tracked files plus .whl, at most 64 MiB: slim the Mitsuba
# wheel (python3 ci/device_wheel_slim.py) and, where that is still over, untrack what the
# run does not read for the call and put it back after it:
#   git rm -r -q --cached results lab/notes/data && printf '/results/\n/lab/notes/data/\n' \
#     >> .git/info/exclude          # ... the device call ...
#   git reset -q && sed -i '/^\/results\/$/d;/^\/lab\/notes\/data\/$/d' .git/info/exclude
# (the goldens stay: the CUDA tests read them; commit nothing in between).
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
# The machine's own Python is the one with numpy and pillow (PyTorch's venv).
py=""
for c in /opt/torch/.venv/bin/python3 $(type -ap python3 python3.12 python); do
  if "$c" -c 'import numpy' 2>/dev/null; then py=$c; break; fi
done
[ -n "$py" ] || { echo "device: no Python with numpy found" >&2; exit 1; }
echo "device: using $py"

"$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
  --target /tmp/site .whl/*.whl 2>&1 | grep -v -i warning
export PYTHONPATH=/tmp/site:$PWD
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
"$py" -c "import drjit as dr, mitsuba as mi; print('drjit', dr.__version__, 'mitsuba', mi.__version__, 'cuda', dr.has_backend(dr.JitBackend.CUDA))"
what=${1:-tests}; shift || true
case "$what" in
  tests) "$py" -m pytest -q -x -k cuda -p no:cacheprovider "$@" tests/ ;;
  bench) "$py" -m whitted bench --backend cuda --out "${OUT:-results}" --force "$@" ;;
  run) "$py" -m whitted "$@" ;;
  py) "$py" "$@" ;;
esac
