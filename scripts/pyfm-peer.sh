#!/usr/bin/env bash
# Runs the pyFM accuracy peer on the pairs of a `shapeforest eval --out OUT` run.
# Usage: scripts/pyfm-peer.sh OUT
# Creates .venv-bench (if absent) and installs pyfmaps and potpourri3d into it.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
out="${1:?usage: scripts/pyfm-peer.sh OUT (the --out folder of shapeforest eval)}"
venv="$root/.venv-bench"
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
fi
if ! "$venv/bin/python" -c "import pyFM, potpourri3d" 2>/dev/null; then
  "$venv/bin/pip" install --quiet pyfmaps potpourri3d
fi
exec "$venv/bin/python" "$root/scripts/pyfm_peer.py" "$out"
