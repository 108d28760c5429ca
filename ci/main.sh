#!/usr/bin/env bash
# The main job on the default scene: render it (EXR + PNG) and write the side-by-side
# comparison report against its Mitsuba golden image, into out/ (or $1).
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash ci/setup.sh
. ci/env.sh
out=${1:-out}
scene=scenes/cornell_box.toml
.venv/bin/whitted render "$scene" --view all --out "$out/render" --overwrite
.venv/bin/whitted compare "$scene" --view all --out "$out/report" --force
