"""Execute book pages ahead of the build, into a jupyter-cache that the build then reads.

``make book`` (scripts/build-book.sh) runs this on the exercise pages while the pipeline runs, at the
lowest CPU priority (``--background``: this process and its kernels at nice 19, their sessions too, see
:func:`lowest_priority`): they need no run folder (their inputs come from
``scrppl.exercises.inputs``), so their kernels take only the CPU time the pipeline leaves idle (its fits
and trials keep about 1.5 of 2 cores busy), and the Sphinx build has fewer pages to execute. When the
pipeline ends, build-book.sh stops this script (SIGUSR1: nbclient takes SIGTERM and SIGINT over while a
page executes): the page being executed is abandoned (its kernel killed, nothing cached) and the build
executes it, and every page not reached, itself.

After the pipeline, build-book.sh runs it again in the foreground on every page not yet cached (the
chapters, and the exercise pages the background pass did not reach): ``--jobs 2`` executes two pages at a
time, each worker taking the next page as soon as it is free, and ``--longest-first`` hands them out most
expensive first by the recorded build's page times (``benchmarks/results/book.json``). The Sphinx build
then only reads the cache; before, it executed these pages in its fixed reading slices, which left one
core idle near the end.

Each page is read with myst-nb's own reader and the book's MyST settings (so jupyter-cache gives it the
key the build computes), executed in its own folder as the build would, and stored with its execution
time; ``--times`` (the list of cached pages the build reads) is rewritten after each page. A page that
fails is not cached: the build executes it again and reports its error as for any page.

The cache is keyed on a page's code cells only, so it is only valid for one build: build-book.sh empties it
first and the build reads it through ``SCRPPL_BOOK_PREEXECUTED`` (book/_ext/scrppl_preexecuted.py); a
build without that variable executes every page itself.

Run: ``python scripts/pre_execute.py --cache DIR [--times FILE] [--jobs N] [--longest-first] PAGE.md ...``;
exit status 1 if a page fails. A ``--times`` file that exists keeps the pages it lists.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import yaml

BOOK = Path(__file__).absolute().parents[1] / "book"  # not resolved (book/exercises is a link)
#: The recorded build: its ``executed_pages_s`` are the costs ``--longest-first`` orders the pages by.
RECORD = BOOK.parent / "benchmarks" / "results" / "book.json"


def md_config():
    """The MyST parser settings of the book (``parse:`` of book/_config.yml) as myst-nb reads pages."""
    from myst_parser.config.main import MdParserConfig

    parse = yaml.safe_load((BOOK / "_config.yml").read_text()).get("parse", {}) or {}
    return MdParserConfig(enable_extensions=set(parse.get("myst_enable_extensions", [])))


def execute_timeout() -> int:
    """``execute: timeout`` of book/_config.yml (seconds a cell may take)."""
    return int(yaml.safe_load((BOOK / "_config.yml").read_text())["execute"].get("timeout", 900))


def read_page(path: Path, config=None):
    """The notebook myst-nb makes of a MyST page (its code cells are what the cache keys on)."""
    from myst_nb.core.read import read_myst_markdown_notebook

    return read_myst_markdown_notebook(
        path.read_text(), config=config or md_config(), add_source_map=True, path=str(path)
    )


class _Stop:
    """SIGUSR1 handling: stop now, unless a page is being written to the cache (then right after it).

    Stopping kills this process's kernels (each runs in its own session, so they would outlive it), waits
    until they are gone, and exits with status 143; a page whose execution is cut short is never cached.
    """

    def __init__(self) -> None:
        self.writing = False
        self.pending = False

    def __call__(self, signum=None, frame=None) -> None:
        if self.writing:
            self.pending = True
            return
        self.now()

    def now(self) -> None:
        import psutil

        children = psutil.Process().children(recursive=True)
        for child in children:
            try:
                child.kill()
            except psutil.Error:
                pass
        # SIGKILL is delivered when the process is next scheduled: on a busy machine a kernel can still be
        # running a moment after kill(); wait until each is gone (a child of this process is reaped here)
        psutil.wait_procs(children, timeout=10)
        os._exit(143)


def lowest_priority(pid: int) -> None:
    """Give process ``pid`` the lowest CPU priority: nice 19, and nice 19 for its autogroup.

    A kernel runs in a session of its own, and where the scheduler groups processes by session
    (``/proc/sys/kernel/sched_autogroup_enabled``, on by default on many Linux systems) a process's nice
    value only counts against the processes of its own session: the kernel's session would share the CPU
    equally with the pipeline's, whatever its nice value. The session's own nice value
    (``/proc/<pid>/autogroup``) is what weighs it against the others; it is only set for a process that
    leads its session (a kernel), never for one that shares the session of ``make book`` and the
    pipeline. Best effort: a process that has gone or a system without autogroups is left as it is.
    """
    try:
        os.setpriority(os.PRIO_PROCESS, pid, 19)
        leads_session = os.getsid(pid) == pid
    except OSError:
        return
    if leads_session:
        try:
            with open(f"/proc/{pid}/autogroup", "w") as f:
                f.write("19")
        except OSError:
            pass


def _lower_kernels(interval: float = 0.2) -> None:
    """Start a thread that gives every new child process (the kernels) :func:`lowest_priority`."""
    import threading

    import psutil

    def watch() -> None:
        me, seen = psutil.Process(), set()
        while True:
            try:
                for child in me.children(recursive=True):
                    if child.pid not in seen:
                        seen.add(child.pid)
                        lowest_priority(child.pid)
            except psutil.Error:
                pass
            time.sleep(interval)

    threading.Thread(target=watch, daemon=True).start()


def page_name(page: Path) -> str:
    """The page's name in the book (its Sphinx document name), else its path without the suffix."""
    return str(
        page.with_suffix("").relative_to(BOOK)
        if page.is_relative_to(BOOK)
        else page.with_suffix("")
    )


def longest_first(pages: list[Path], costs: dict[str, float]) -> list[Path]:
    """``pages`` by recorded cost, most expensive first (unknown pages first too: they may be long).

    Handed to ``--jobs`` workers in this order, the pages are scheduled longest-processing-time first,
    whose finish is within 4/3 of the best possible.
    """
    return sorted(pages, key=lambda p: (-costs.get(page_name(p.absolute()), float("inf")), str(p)))


def recorded_costs(record: Path = RECORD) -> dict[str, float]:
    """Execution seconds per page of the recorded build (empty if there is no readable record)."""
    try:
        costs = json.loads(record.read_text()).get("executed_pages_s", {})
        return {str(k): float(v) for k, v in costs.items()}
    except (OSError, ValueError, AttributeError, TypeError):
        return {}


def _read_times(path: Path | None) -> dict[str, float]:
    if path is None or not path.exists():
        return {}
    try:
        times = json.loads(path.read_text())
    except ValueError:
        return {}
    return times if isinstance(times, dict) else {}


def _write_times(path: Path, times: dict[str, float]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(times, indent=2) + "\n")
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    from jupyter_cache import get_cache
    from jupyter_cache.base import CacheBundleIn
    from jupyter_cache.executors.utils import single_nb_execution

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--cache", type=Path, required=True, help="the jupyter-cache folder the build reads"
    )
    ap.add_argument("--times", type=Path, default=None, help="write {page: seconds} here (JSON)")
    ap.add_argument(
        "--background",
        action="store_true",
        help="run this process and its kernels at the lowest CPU priority (lowest_priority)",
    )
    ap.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="pages executed at once, each by its own kernel (not with --background)",
    )
    ap.add_argument(
        "--longest-first",
        action="store_true",
        help="take the pages most expensive first, by the recorded build's page times (book.json)",
    )
    ap.add_argument("pages", type=Path, nargs="+")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f"--jobs must be at least 1, not {args.jobs}")
    if args.background and args.jobs > 1:
        ap.error("--background executes one page at a time (its stop signal waits for one page)")
    if args.background:
        lowest_priority(os.getpid())
        _lower_kernels()
    cache = get_cache(str(args.cache))
    config, timeout = md_config(), execute_timeout()
    # pages listed by an earlier run into the same cache stay listed
    times, failed = _read_times(args.times), []
    stop = _Stop()
    signal.signal(signal.SIGUSR1, stop)
    if args.times is not None:
        _write_times(args.times, times)
    pages = [p.absolute() for p in args.pages]  # not resolved: an exercise page links to notebooks/
    if args.longest_first:
        pages = longest_first(pages, recorded_costs())
    lock = threading.Lock()  # one page at a time into the cache and the times file

    def execute(page: Path) -> None:
        nb = read_page(page, config)
        t0 = time.perf_counter()
        result = single_nb_execution(
            nb, cwd=str(page.parent), timeout=timeout, allow_errors=False, meta_override=True
        )
        name = page_name(page)
        if result.err is not None:
            with lock:
                failed.append(name)
            print(f"[pre-execute] {name}: FAILED\n{result.exc_string}", file=sys.stderr, flush=True)
            return
        with lock:
            stop.writing = True  # a SIGUSR1 now waits until the page is cached and listed
            cache.cache_notebook_bundle(
                CacheBundleIn(nb, str(page), data={"execution_seconds": result.time}),
                check_validity=False,
                overwrite=True,
            )
            times[name] = round(result.time, 2)
            if args.times is not None:
                _write_times(args.times, times)
            stop.writing = False
        print(f"[pre-execute] {name}: {time.perf_counter() - t0:.1f} s", flush=True)
        if stop.pending:
            stop.now()

    if args.jobs == 1:
        for page in pages:
            execute(page)
    else:
        queue = list(pages)

        def worker() -> None:
            from jupyter_core.utils import ensure_event_loop

            try:
                while True:
                    with lock:
                        if not queue:
                            return
                        page = queue.pop(0)
                    try:
                        execute(page)
                    # a page that cannot be read or run is left to the build, which shows why
                    except Exception as err:
                        with lock:
                            failed.append(page_name(page))
                        print(f"[pre-execute] {page_name(page)}: FAILED ({err!r})", file=sys.stderr)
            finally:
                # nbclient ran the pages on an event loop of this thread's own: close it with the thread
                ensure_event_loop().close()

        threads = [threading.Thread(target=worker) for _ in range(min(args.jobs, len(queue)))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
