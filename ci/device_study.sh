#!/usr/bin/env bash
# The accuracy-vs-time study on a lent GPU machine (issue 13), within a hard wall-clock limit:
#
#   OUT=... bash ci/device_study.sh [LABEL]          # LABEL names the device folder (h200)
#
# 1. installs the wheels carried in .whl/ (no network there) into /tmp/site, as ci/device.sh
#    does (skipped when drjit, mitsuba and dask already import). The study needs drjit,
#    openexr, flip-evaluator, dask, distributed, tornado, tblib, zict, partd, locket and, for
#    ΔE2000, colour-science (about 19 MB); not Mitsuba (23 MB), which it never imports;
# 2. the executor check: a tiny sweep in-process and on one Dask worker (`--workers 1`, which
#    gets the GPU through CUDA_VISIBLE_DEVICES); prints whether the JSON agrees minus timings;
# 3. the study itself (profile $PROFILE, default gpu: the seed scenes and the glass bunny)
#    with --budget-minutes set from the time left, under `timeout`, then the tables, plots
#    and HTML from whatever study.json holds (a run cut short resumes: unpack the tarball's
#    study/LABEL into results/study/LABEL, commit, and run the same command again);
# 4. packs everything into $OUT/study-LABEL.tar.gz (plus the two logs: three files).
#
# Environment: OUT (default /tmp/study-out), BACKEND (cuda), PROFILE (gpu), TOTAL_S (400:
# the whole script's wall budget, leave ~20 s under the machine's limit), SCENES (default:
# the study's seed scenes), CHECK_S (the executor check's limit, default min(120, left/4); 0
# skips it), EXTRA (more `whitted study` options), PYTHON (default: the machine's Python).
# Tested on the CPU with: BACKEND=llvm PROFILE=tiny TOTAL_S=300 PYTHON=.venv/bin/python.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
t0=$(date +%s)
label=${1:-h200}
OUT=${OUT:-/tmp/study-out}
backend=${BACKEND:-cuda}
profile=${PROFILE:-gpu}
total=${TOTAL_S:-400}
read -r -a scenes <<< "${SCENES:-}"
left() { echo $(( total - ($(date +%s) - t0) )); }
mkdir -p "$OUT"
work=$(mktemp -d /tmp/study-work.XXXX)
log="$OUT/study-$label.log"
checklog="$OUT/executor-check-$label.log"

py=${PYTHON:-}
if [ -z "$py" ]; then
  for c in /opt/torch/.venv/bin/python3 $(type -ap python3 python3.12 python); do
    if "$c" -c 'import numpy' 2>/dev/null; then py=$c; break; fi
  done
fi
[ -n "$py" ] || { echo "device_study: no Python with numpy found" >&2; exit 1; }
if ! "$py" -c 'import drjit, mitsuba, dask.distributed' 2>/dev/null; then
  "$py" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl 2>&1 | grep -v -i warning
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH}
fi
[ "$backend" = llvm ] && [ -f ci/env.sh ] && . ci/env.sh
echo "device_study: $py, backend $backend, profile $profile, $(left) s left"
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total \
  --format=csv,noheader

# ---- 2. executor check (tiny sweep, cornell_box): in-process vs one Dask worker ------------
# CHECK_S=0 skips it (a run that only resumes points, its check already committed).
lim=${CHECK_S:-$(( $(left) / 4 ))}; [ "$lim" -gt 120 ] && [ -z "${CHECK_S:-}" ] && lim=120
if [ "$lim" -gt 0 ]; then
  timeout -k 5 "$lim" "$py" -m whitted.study cornell_box --profile tiny --backend "$backend" \
    --factors spp,accel --no-grid --check-executor --workers 1 --out "$work/executor-check" \
    > "$checklog" 2>&1
  rc=$?
  [ $rc = 124 ] && echo "executor check: TIMED OUT after $lim s" >> "$checklog"
  grep -E "executor check|error|Error" "$checklog" | tail -5
  echo "executor check: exit $rc ($(left) s left)"
else
  echo "executor check: skipped (CHECK_S=0)" | tee "$checklog"
fi

# ---- 3. the study, under a hard timeout; budget = time left minus report, pack, slack -----
# A committed partial run (results/study/LABEL/study.json) is resumed, not repeated.
mkdir -p "$work/study"
[ -f "results/study/$label/study.json" ] && cp -r "results/study/$label" "$work/study/" \
  && echo "study: resuming results/study/$label"
hard=$(( $(left) - 45 ))
budget=$(( hard - 60 ))
if [ "$budget" -gt 30 ]; then
  mins=$(awk "BEGIN{printf \"%.2f\", $budget / 60}")
  echo "study: budget $mins min, hard limit $hard s"
  timeout -k 5 -s INT "$hard" "$py" -m whitted.study "${scenes[@]}" --profile "$profile" \
    --backend "$backend" --out "$work/study/$label" --budget-minutes "$mins" --no-progress \
    ${EXTRA:-} \
    > "$log" 2>&1
  echo "study: exit $? ($(left) s left)"; tail -4 "$log"
  [ -f "$work/study/$label/study.json" ] && timeout -k 5 40 "$py" -m whitted.study \
    --report-only --out "$work/study/$label" >> "$log" 2>&1
else
  echo "study: no time left ($budget s)" | tee -a "$log"
fi

# ---- 4. pack (the own-reference cache stays behind) ---------------------------------------
cp "$checklog" "$work/" 2>/dev/null
tar czf "$OUT/study-$label.tar.gz" -C "$work" --exclude=cache study executor-check \
  "$(basename "$checklog")" 2>/dev/null
ls -la "$OUT"; echo "device_study: done in $(( $(date +%s) - t0 )) s"
