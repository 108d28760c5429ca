#!/usr/bin/env bash
# Idempotent set-up on a bare Debian machine with Python >= 3.11 and no GPU:
#   - libLLVM 19 for Dr.Jit's LLVM (CPU) backend (Debian's default LLVM 14/15 aborts on
#     "Cannot select ... fminimum"), Chromium for the report screenshot test and
#     chromium-driver for the viewer's browser test (selenium);
#   - a virtual environment in .venv with the project and its reference/study/test/view extras.
# Re-running it does nothing that is already done. Set WHITTED_SKIP_APT=1 to skip apt-get.
set -euo pipefail
root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$root"

# ---- system packages ------------------------------------------------------------------
if [ "${WHITTED_SKIP_APT:-0}" != 1 ]; then
  need=()
  ls /usr/lib/*/libLLVM*.so* 2>/dev/null | grep -q -- '19' || need+=(libllvm19)
  command -v chromium >/dev/null 2>&1 || need+=(chromium)
  command -v chromedriver >/dev/null 2>&1 || need+=(chromium-driver)
  if [ ${#need[@]} -gt 0 ]; then
    sudo=""; [ "$(id -u)" = 0 ] || sudo="sudo"
    echo "setup: apt-get install ${need[*]}"
    $sudo apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${need[@]}" >/dev/null
  fi
fi

# ---- Python environment ----------------------------------------------------------------
py=${PYTHON:-python3}
"$py" -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else 1)' \
  || { echo "setup: Python >= 3.11 required ($("$py" --version 2>&1))" >&2; exit 1; }
[ -x .venv/bin/python ] || "$py" -m venv .venv
stamp=.venv/.whitted-installed
# Reinstall when pyproject.toml or the set of packages changes (an editable install maps
# the top-level packages that existed when it was made).
want=$( (cat pyproject.toml; ls -d -- */__init__.py) | sha256sum | cut -d' ' -f1)
if [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "setup: pip install -e .[reference,study,test,view]"
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -e ".[reference,study,test,view]"
  echo "$want" > "$stamp"
fi
