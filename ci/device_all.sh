#!/usr/bin/env bash
# One combined run on a lent GPU machine (see ci/device.sh for the set-up it shares):
#   bash ci/device_all.sh STEP...      steps: tests hard bench peer frames routine study
# Each step has its own time limit (SIGINT first, so partial results are written) and its
# own folder under $OUT; logs go to $OUT/<step>.log.
set -uo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
out=${OUT:-out/device}
mkdir -p "$out"
step() {  # name, seconds, command...
  local name=$1 secs=$2; shift 2
  echo "=== $name (limit ${secs} s)"
  local t0=$SECONDS
  timeout -s INT -k 20 "$secs" "$@" > "$out/$name.log" 2>&1
  echo "=== $name: exit $? after $((SECONDS - t0)) s"
  tail -n 25 "$out/$name.log"
}
for s in "$@"; do
  case "$s" in
    tests) step tests 180 bash ci/device.sh tests ;;
    hard)  step hard 240 bash ci/device.sh run hard-cases --backend cuda \
             --cases closed_mesh,reintersect,far_origin --rays 100000000 --chunk 16777216 \
             --out "$out/hard" --overwrite ;;
    bench) step bench 300 env OUT="$out/bench" bash ci/device.sh bench --parts throughput ;;
    peer)  step peer 280 env OUT="$out/peer" bash ci/device.sh bench --parts peer ;;
    frames) step frames 150 bash ci/device.sh py lab/probes/probe_frame.py --backend cuda \
              --out "$out/frames" --force ;;
    routine) step routine 200 bash ci/device.sh py lab/probes/routine_cost.py --backend cuda \
               --out "$out/routine" ;;
    study) step study 420 env OUT="$out" TOTAL_S=400 bash ci/device_study.sh h200 ;;
    *) echo "unknown step $s" >&2; exit 2 ;;
  esac
done
