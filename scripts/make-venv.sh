#!/usr/bin/env bash
# Create .venv from environment.lock (every package pinned and hash-checked), then install scrppl into it
# in editable mode without touching the locked dependencies.
set -euo pipefail
cd "$(dirname "$0")/.."
python=$(bash scripts/find-python.sh)
echo "scrppl: creating .venv with $python ($("$python" --version 2>&1)) from environment.lock"
rm -rf .venv
"$python" -m venv .venv
.venv/bin/python -m pip install --quiet --upgrade pip
.venv/bin/python -m pip install --quiet --require-hashes -r environment.lock
.venv/bin/python -m pip install --quiet --no-deps --no-build-isolation -e .
touch .venv/.installed
echo "scrppl: environment ready (.venv)"
