#!/usr/bin/env bash
# The test suite: ruff (lint + import order, config in pyproject.toml), then pytest (LLVM
# backend; CUDA too where a GPU is present). Extra args go to pytest.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"
bash ci/setup.sh
. ci/env.sh
.venv/bin/ruff check .
exec .venv/bin/python -m pytest -q -rs "$@"
