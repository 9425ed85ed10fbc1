#!/usr/bin/env bash
# Runs the whole test suite (unit, integration, doc tests). First renders the
# corpus scene the pinned-figure tests use (Blender, cached under
# target/ci-corpus; scripts/corpus/build.py), so the generator cannot rot.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=python3
# Debian's Python has python3-numpy and python3-opencv; a python3 earlier on
# PATH (pyenv, a venv) may not.
[ -x /usr/bin/python3 ] && PY=/usr/bin/python3
"$PY" scripts/corpus/build.py --out target/ci-corpus --seeds 1 --size 128x64 --samples 8
# The KTX2 client tests/export.rs reads lumiprobe's cubes with.
{ [ -d tools/js/node_modules/ktx-parse ] && [ -d tools/js/node_modules/three ]; } || npm ci --prefix tools/js --no-audit --no-fund
export LUMIPROBE_SMOKE_SCENE="$PWD/target/ci-corpus/s0001_128x64"
cargo test
