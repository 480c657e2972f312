#!/usr/bin/env bash
# Side-by-side benchmark: shapeforest's eigensolver and heat method against scipy's eigsh and
# potpourri3d on the same meshes, in the same run (ours first, then the peers, back to back).
# Installs the peers from PyPI into a local virtualenv (.venv-bench, ignored by git) the first
# time; needs python3 with the venv module and a network connection for that first run.
#   scripts/bench-peers.sh [extra `shapeforest bench --out` arguments]
#   e.g. scripts/bench-peers.sh --sizes 5000,20000 --data /path/to/data --forest
# Best of 3 runs unless --repeat N is given. The machine's load average is printed before our
# runs, between ours and the peer's, and after the peer's, and kept in the report: run it on a
# quiet machine (load below 1, no build or test running), or the ratios mean little.
# Set BENCH_DIR=DIR to keep the meshes and JSON results there (default: a temporary folder).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=.venv-bench
if [ ! -x "$venv/bin/python" ]; then
  if ! python3 -m venv "$venv"; then
    echo "bench-peers.sh: 'python3 -m venv' failed (on Debian/Ubuntu: apt install python3-venv)" >&2
    rm -rf "$venv"
    exit 1
  fi
  "$venv/bin/pip" install --quiet --upgrade pip
  if ! "$venv/bin/pip" install --quiet numpy scipy potpourri3d; then
    echo "bench-peers.sh: installing numpy scipy potpourri3d failed" >&2
    rm -rf "$venv"
    exit 1
  fi
fi
cargo build --release --quiet
if [ -n "${BENCH_DIR:-}" ]; then
  work=$BENCH_DIR
  mkdir -p "$work"
else
  work=$(mktemp -d)
  trap 'rm -rf "$work"' EXIT
fi
echo "# $(date -u '+%Y-%m-%d %H:%M UTC'), $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo 2>/dev/null | cut -d: -f2 | sed 's/^ //')" >&2
load() { cut -d' ' -f1-3 /proc/loadavg 2>/dev/null || echo unknown; }
repeat_args=(--repeat 3)
for a in "$@"; do
  case $a in --repeat|--repeat=*) repeat_args=() ;; esac
done
echo "# load average before: $(load)" >&2
./target/release/shapeforest bench --out "$work" "${repeat_args[@]}" "$@"
echo "# load average after shapeforest, before the peer: $(load)" >&2
# BLAS threads of the peer: 1 by default. scipy's eigsh is SuperLU (sequential) plus ARPACK, and
# on a 2-core machine shared with other work, 2 OpenBLAS threads made it 3-10x slower (spinning
# threads) than 1; set PEER_THREADS to try more.
peer_threads=${PEER_THREADS:-1}
echo "# peer BLAS threads: $peer_threads" >&2
OMP_NUM_THREADS=$peer_threads OPENBLAS_NUM_THREADS=$peer_threads MKL_NUM_THREADS=$peer_threads \
  "$venv/bin/python" scripts/peer_bench.py "$work/manifest.json" "$work/peer.json"
peer_load_after=$(load)
echo "# load average after the peer: $peer_load_after" >&2
./target/release/shapeforest bench --report "$work"
echo
echo "Load average after the peer's runs: $peer_load_after."
