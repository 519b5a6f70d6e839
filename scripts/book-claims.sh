#!/usr/bin/env bash
# Every chapter's asserted claims against the book profile of one seed: `make claims SEED=1`.
# Runs (or resumes) `scrppl reproduce --profile book --seed SEED` into results-book[-seed<SEED>][-native]/,
# then executes every chapter against it with each assert recorded instead of raised
# (scripts/book_claims.py); exits 1 if any claim does not hold. CI runs it for a second seed.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=.venv
SEED=${1:-${SEED:-1}}
results=results-book
[ "$SEED" != 0 ] && results=$results-seed$SEED
[ "${SCRPPL_NATIVE_CPU:-0}" != 0 ] && results=$results-native
$VENV/bin/scrppl reproduce --profile book --seed "$SEED" --out "$results"
export JAX_PLATFORMS=cpu
unset MPLBACKEND
eval "$($VENV/bin/python -c 'from scrppl.numerics import shell_exports; print(shell_exports())')"
# JAX's persistent compilation cache under the scrppl cache (SCRPPL_JAX_CACHE=0: none): the pages
# reuse what the pipeline and the earlier pages compiled (the same bytes, less time)
eval "$($VENV/bin/python -c 'from scrppl._io import compilation_cache_exports; print(compilation_cache_exports())')"
name=seed$SEED
[ "${SCRPPL_NATIVE_CPU:-0}" != 0 ] && name=$name-native
$VENV/bin/python scripts/book_claims.py --run "$name=$results" --require-all
