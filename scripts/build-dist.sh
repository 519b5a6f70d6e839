#!/usr/bin/env bash
# Build scrppl's sdist and wheel (`make dist`): the wheel is built from the sdist, so a file missing from
# the sdist (the example models in scrppl/data/) is missing from the wheel too and the wheel test fails.
# Offline: the build backend (setuptools) is the one pinned in environment.lock, installed in .venv.
# Usage: scripts/build-dist.sh [OUT_DIR] (default dist/)
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-dist}
rm -rf "$out"
# setuptools writes scrppl.egg-info/ here while it makes the sdist: remove it afterwards unless it was here
had_egg_info=0
[ -d scrppl.egg-info ] && had_egg_info=1
log=$(mktemp)
if ! .venv/bin/uv build --offline --no-build-isolation --python .venv/bin/python --out-dir "$out" . \
    >"$log" 2>&1; then
  cat "$log" >&2
  exit 1
fi
rm -f "$log" "$out/.gitignore"
[ "$had_egg_info" = 1 ] || rm -rf scrppl.egg-info
ls "$out"/scrppl-*.tar.gz "$out"/scrppl-*.whl
