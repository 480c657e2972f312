#!/usr/bin/env bash
# Side-by-side benchmark: shapeforest's eigensolver and heat method against scipy's eigsh and
# potpourri3d on the same meshes, in the same run. Installs the peers from PyPI into a local
# virtualenv (.venv-bench, ignored by git) the first time.
#   scripts/bench-peers.sh [extra `shapeforest bench` arguments, e.g. --sizes 5000,20000,50000]
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv-bench
if [ ! -x "$venv/bin/python" ]; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install --quiet --upgrade pip
  "$venv/bin/pip" install --quiet numpy scipy potpourri3d
fi
cargo build --release --quiet
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
./target/release/shapeforest bench --out "$work" "$@"
OMP_NUM_THREADS=2 "$venv/bin/python" scripts/peer_bench.py "$work/manifest.json" "$work/peer.json"
./target/release/shapeforest bench --report "$work"
