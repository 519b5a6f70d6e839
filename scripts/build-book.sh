#!/usr/bin/env bash
# Build the executed HTML book offline, then check every page in headless Chromium.
#
# 1. Results: run (or resume) the small `book` profile of `scrppl reproduce` into results-book/, or use the
#    run folder named by $SCRPPL_RESULTS (`make book RESULTS=results` for a full run). Chapters read the
#    chosen folder through $SCRPPL_RESULTS and say on each page which run they show. Meanwhile the exercise
#    pages, which need no run folder, execute at the lowest CPU priority on what the pipeline leaves idle
#    (scripts/pre_execute.py); those not done when the run ends are left to step 3.
# 2. MathJax 3 from the npm registry into book/_build/.mathjax (not committed; reused when present).
# 3. jupyter-book build: every page executed (those step 1 finished are read from its cache), warnings (and
#    stderr output of any cell) are errors. It also generates the API reference from the docstrings
#    (book/_ext/scrppl_api.py) and puts each notebook page's .ipynb and each exercise page's student copy
#    (scripts/make_student.py, the code of `make student`) in the HTML output's _sources/, offered by the
#    pages' download menus (book/_ext/scrppl_downloads.py).
# 4. scripts/check_book.py: titles, figures, typeset math, no error output, no remote assets, the download
#    links serve notebooks; screenshots.
# Timings go to book/_build/timings.json.
set -euo pipefail
shopt -s inherit_errexit 2>/dev/null || true
cd "$(dirname "$0")/.."
VENV=.venv
SEED=${SEED:-0}
t_start=$(date +%s)

# The exercise pages need no run folder: execute them now, beside the pipeline, at the lowest CPU priority
# (their kernels' sessions too) so that they only take the CPU time it leaves idle (scripts/pre_execute.py
# --background), into a jupyter-cache emptied here, so that it only ever holds this build's pages; the
# build below takes their outputs from it (book/_ext/scrppl_preexecuted.py). SCRPPL_BOOK_PRE=0: none.
PRE=book/_build/.preexecuted
rm -rf "$PRE" && mkdir -p "$PRE"
pre_pid=
if [ "${SCRPPL_BOOK_PRE:-1}" != 0 ]; then
  (
    export JAX_PLATFORMS=cpu PYTHONWARNINGS=${PYTHONWARNINGS:-}
    eval "$($VENV/bin/python -c 'from scrppl.numerics import shell_exports; print(shell_exports())')"
    eval "$($VENV/bin/python -c 'from scrppl._io import compilation_cache_exports; print(compilation_cache_exports())')"
    unset MPLBACKEND
    exec $VENV/bin/python scripts/pre_execute.py --background --cache "$PRE" --times "$PRE/pages.json" \
      book/exercises/[0-9]*.md
  ) > book/_build/pre-execute.log 2>&1 &
  pre_pid=$!
  trap '[ -n "$pre_pid" ] && kill -USR1 $pre_pid 2>/dev/null || true' EXIT
fi

if [ -n "${SCRPPL_RESULTS:-}" ]; then
  results=$SCRPPL_RESULTS
  [ -f "$results/run.json" ] || { echo "[book] $results has no run.json: not a run folder of scrppl reproduce" >&2; exit 1; }
  echo "[book] results: $results (from \$SCRPPL_RESULTS; e.g. a full run's results/)"
else
  # The chapters' asserted claims hold for every seed (benchmarks/results/book-claims.json): the book profile
  # of seed 0 lives in results-book/, another seed's in results-book-seed<k>/, a run with this CPU's own
  # code (SCRPPL_NATIVE_CPU=1, make book CPU=native) in ...-native/.
  results=results-book
  [ "$SEED" != 0 ] && results=$results-seed$SEED
  [ "${SCRPPL_NATIVE_CPU:-0}" != 0 ] && results=$results-native
  echo "[book] results: the book profile in $results/ (scrppl reproduce --profile book --seed $SEED; current stages are skipped)"
  $VENV/bin/scrppl reproduce --profile book --seed "$SEED" --out "$results"
fi
t_results=$(date +%s)
if [ -n "$pre_pid" ]; then
  # stop the pre-execution (a page being cached is finished first; one being executed is left to the build)
  kill -USR1 $pre_pid 2>/dev/null || true
  wait $pre_pid 2>/dev/null || true
  pre_pid=
  echo "[book] exercise pages executed beside the pipeline: $($VENV/bin/python -c 'import json, sys; print(len(json.load(open(sys.argv[1]))))' "$PRE/pages.json" 2>/dev/null || echo 0) (book/_build/pre-execute.log)"
fi

# Every chapter shows more code than it hides (hidden cells only glue, format and assert).
$VENV/bin/python scripts/book_code_balance.py --check

bash scripts/install-mathjax.sh

if ! command -v chromium >/dev/null 2>&1 && ! command -v chromium-browser >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[book] installing Chromium (Debian package) for the page check"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
  fi
fi

# JAX on the 2-core CI machines: no accelerators, quiet.
# Notebooks execute in their own folders: hand them an absolute path.
export SCRPPL_RESULTS=$(cd "$results" && pwd) JAX_PLATFORMS=cpu PYTHONWARNINGS=${PYTHONWARNINGS:-}
export SCRPPL_BOOK_PREEXECUTED=$(cd "$PRE" && pwd)
# The kernels import NumPy before scrppl: hand them the portable numerics of the scrppl commands
# (scrppl.numerics; nothing with SCRPPL_NATIVE_CPU=1).
eval "$($VENV/bin/python -c 'from scrppl.numerics import shell_exports; print(shell_exports())')"
# JAX's persistent compilation cache under the scrppl cache (SCRPPL_JAX_CACHE=0: none): the pages
# reuse what the pipeline and the earlier pages compiled (the same bytes, less time)
eval "$($VENV/bin/python -c 'from scrppl._io import compilation_cache_exports; print(compilation_cache_exports())')"
# No MPLBACKEND: Jupyter kernels then use the inline backend and show the figures a cell draws.
unset MPLBACKEND
rm -rf book/_build/html book/_build/jupyter_execute book/_build/.doctrees
t_build0=$(date +%s)
# Every other page executes now, BOOK_JOBS at a time, most expensive first (by the recorded build's page
# times), into the same cache: scheduled this way the pages keep both cores busy to the end, where Sphinx's
# fixed reading slices left one idle for about half a minute. The build below then only reads them (a page
# that failed here is executed by the build, which reports its error). SCRPPL_BOOK_PRE=0: none.
if [ "${SCRPPL_BOOK_PRE:-1}" != 0 ]; then
  [ -f "$PRE/pages.json" ] && cp "$PRE/pages.json" "$PRE/beside.json" || echo '{}' > "$PRE/beside.json"
  rest=()
  for page in book/chapters/[0-9]*.md book/exercises/[0-9]*.md; do
    name=${page#book/}; name=${name%.md}
    grep -q "\"$name\"" "$PRE/beside.json" || rest+=("$page")
  done
  if [ ${#rest[@]} -gt 0 ]; then
    jobs=${BOOK_JOBS:-$( [ "$(nproc)" -gt 1 ] && echo 2 || echo 1 )}
    echo "[book] executing ${#rest[@]} pages, $jobs at a time, most expensive first"
    $VENV/bin/python scripts/pre_execute.py --jobs "$jobs" \
      --longest-first --cache "$PRE" --times "$PRE/pages.json" "${rest[@]}" 2> book/_build/execute.log \
      || echo "[book] a page failed to execute (book/_build/execute.log): the build executes it again and shows why"
  fi
fi
mkdir -p book/_build
$VENV/bin/python scripts/jupyter_book_build.py build -W -n --keep-going book/ 2>&1 | tee book/_build/jupyter-book.log
t_build=$(date +%s)
$VENV/bin/python scripts/check_book.py --html book/_build/html --toc book/_toc.yml
t_end=$(date +%s)
$VENV/bin/python - "$results" $((t_results - t_start)) $((t_build - t_build0)) $((t_end - t_build)) $((t_end - t_start)) <<'PY'
import json, sys
from pathlib import Path
results, t_res, t_build, t_check, total = sys.argv[1], *map(int, sys.argv[2:])
import re
pages = {}
for line in Path("book/_build/jupyter-book.log").read_text(errors="replace").splitlines():
    m = re.search(r"book/(\S+)\.md: Executed notebook in ([0-9.]+) seconds", line)
    if m:
        pages[m.group(1)] = float(m.group(2))
# the exercise pages executed beside the pipeline (scripts/pre_execute.py): their own times
pre_file = Path("book/_build/.preexecuted/pages.json")
pre = json.loads(pre_file.read_text()) if pre_file.exists() else {}
pages.update(pre)
beside_file = Path("book/_build/.preexecuted/beside.json")
beside = json.loads(beside_file.read_text()) if beside_file.exists() else {}
Path("book/_build/timings.json").write_text(json.dumps(
    {"results": results, "results_s": t_res, "build_s": t_build, "check_s": t_check, "total_s": total,
     "executed_pages_s": pages, "executed_beside_the_pipeline": sorted(beside)}, indent=2) + "\n")
print(f"[book] done in {total} s (results {t_res} s, build {t_build} s, page check {t_check} s)")
PY
