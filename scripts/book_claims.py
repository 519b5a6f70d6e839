"""Which of the book's claims hold in which runs: every ``assert`` of the chapters, run against several runs.

A chapter states a claim in its prose and checks it in a hidden cell with ``assert`` (or a
``np.testing.assert_*`` call). A claim that holds for one seed on one machine is not a finding, so this
script executes every chapter against each of several ``scrppl reproduce --profile book`` runs (other
seeds, or the same seed with the CPU features narrowed) with every assert *instrumented*: instead of
stopping the chapter, each assert records whether it held, and the chapter goes on. The result lists every
assert with the runs it held in.

Usage::

    # run the book profile for seeds 1..4 first (make book SEED=k, or scrppl reproduce --profile book)
    .venv/bin/python scripts/book_claims.py --run seed0=results-book --run seed1=results-book-seed1 \\
        --out benchmarks/results/book-claims.json
    # CI: one extra run, fail when any claim does not hold in it
    .venv/bin/python scripts/book_claims.py --run seed1=results-book-seed1 --require-all

Pages run ``--jobs`` at a time (default 2), each in its own kernel.

Each ``--run NAME=FOLDER`` names a run folder of ``scrppl reproduce`` (with its run.json). ``--pages``
restricts the pages (default: every chapter, ``book/chapters/*.md``). With ``--out`` an existing record is
updated: the runs given replace those of the same name, and the others are kept as long as the assert
text they were recorded for is still in the chapter.

How a claim is identified: by its page and the assert's source text (with a counter when one page has two
identical asserts), so that editing the prose around it does not lose its history; its line in the page
is recorded for reading. A cell that raises anything else than an assertion is recorded as a failure of
the page (``"<cell error>"``), with the error.

Exit status: 0; 1 with ``--require-all`` when an assert failed (or a cell raised) in any given run.
"""

from __future__ import annotations

import argparse
import ast
import asyncio
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import jupytext
import nbformat
from nbclient import NotebookClient

ROOT = Path(__file__).resolve().parent.parent
RECORD_VAR = "SCRPPL_CLAIMS_LOG"

# Defined in the kernel before the page's own cells run.
PRELUDE = f'''
import json as _claims_json, os as _claims_os
def __claim_record(claim_id, ok, detail=""):
    with open(_claims_os.environ["{RECORD_VAR}"], "a") as fh:
        fh.write(_claims_json.dumps({{"id": claim_id, "ok": bool(ok), "detail": str(detail)[:300]}}) + "\\n")
'''


def _magic_free(source: str) -> tuple[str, list[int]]:
    """The cell's source with IPython magics and shell lines blanked (line numbers kept)."""
    lines = source.splitlines()
    blanked = []
    for i, line in enumerate(lines):
        if line.lstrip().startswith(("%", "!")):
            lines[i] = ""
            blanked.append(i)
    return "\n".join(lines), blanked


class _Instrument(ast.NodeTransformer):
    """Replace each ``assert`` and ``*.assert_*(...)`` statement by a recorded, non-raising check."""

    def __init__(self, source: str, cell_line: int, page: str, seen: dict[str, int]):
        self.source = source
        self.cell_line = cell_line
        self.page = page
        self.seen = seen
        self.claims: list[dict] = []

    def _claim(self, node: ast.stmt) -> str:
        text = " ".join(ast.get_source_segment(self.source, node).split())
        n = self.seen.get(text, 0)
        self.seen[text] = n + 1
        claim_id = f"{self.page}::{text}" + (f" [{n + 1}]" if n else "")
        self.claims.append(
            {"id": claim_id, "page": self.page, "line": self.cell_line + node.lineno, "text": text}
        )
        return claim_id

    def _wrap(self, node: ast.stmt, check: list[ast.stmt]) -> list[ast.stmt]:
        claim_id = self._claim(node)
        # try: <check>; record(id, True) / except Exception as e: record(id, False, repr(e))
        record_ok = ast.parse(f"__claim_record({claim_id!r}, True)").body
        handler = ast.ExceptHandler(
            type=ast.Name("Exception", ast.Load()),
            name="__claim_error",
            body=ast.parse(f"__claim_record({claim_id!r}, False, repr(__claim_error))").body,
        )
        return [ast.Try(body=check + record_ok, handlers=[handler], orelse=[], finalbody=[])]

    def visit_Assert(self, node: ast.Assert):
        return self._wrap(node, [node])

    def visit_Expr(self, node: ast.Expr):
        call = node.value
        if (
            isinstance(call, ast.Call)
            and isinstance(call.func, ast.Attribute)
            and call.func.attr.startswith("assert_")
        ):
            return self._wrap(node, [node])
        return self.generic_visit(node)


def instrument_page(path: Path, page: str) -> tuple[nbformat.NotebookNode, list[dict]]:
    """The page as a notebook whose asserts record instead of raising, and the list of its claims."""
    text = path.read_text()
    nb = jupytext.reads(text, fmt="md:myst")
    claims: list[dict] = []
    seen: dict[str, int] = {}
    lines = text.splitlines()
    cursor = 0
    for cell in nb.cells:
        if cell.cell_type != "code":
            continue
        # the cell's first source line in the page (for reading the record)
        first = cell.source.splitlines()[0] if cell.source.strip() else ""
        cell_line = cursor
        for i in range(cursor, len(lines)):
            if lines[i] == first:
                cell_line, cursor = i, i + 1
                break
        src, blanked = _magic_free(cell.source)
        try:
            tree = ast.parse(src)
        except SyntaxError:
            continue
        inst = _Instrument(src, cell_line, page, seen)
        tree = ast.fix_missing_locations(inst.visit(tree))
        if not inst.claims:
            continue
        claims += inst.claims
        magics = [cell.source.splitlines()[i] for i in blanked]
        # keep the cell's display: the last expression of the original cell stays last
        cell.source = "\n".join(magics + [ast.unparse(tree)])
    nb.cells.insert(0, nbformat.v4.new_code_cell(PRELUDE))
    return nb, claims


def run_page(nb, claims, results: Path, log: Path, timeout: int) -> list[dict]:
    """Execute the instrumented page against ``results``; the claims with whether each held."""
    return asyncio.run(run_page_async(nb, claims, results, log, timeout))


async def run_page_async(nb, claims, results: Path, log: Path, timeout: int) -> list[dict]:
    """:func:`run_page` as a coroutine, so that several pages can run at once in one event loop.

    The kernel gets ``SCRPPL_RESULTS`` and the claims log through its own environment (this process's is
    left alone), each page with its own log.
    """
    env = dict(os.environ, SCRPPL_RESULTS=str(results.resolve()), **{RECORD_VAR: str(log)})
    log.write_text("")
    error = None
    try:
        client = NotebookClient(
            nb,
            timeout=timeout,
            kernel_name="python3",
            allow_errors=False,
            resources={"metadata": {"path": str(ROOT / "book" / "chapters")}},
        )
        await client.async_execute(env=env)
    except Exception as exc:  # a cell raised something else than a recorded assert
        error = f"{type(exc).__name__}: {str(exc).strip().splitlines()[-1] if str(exc).strip() else ''}"
    outcome: dict[str, bool] = {}
    details: dict[str, str] = {}
    for line in log.read_text().splitlines():
        rec = json.loads(line)
        outcome[rec["id"]] = outcome.get(rec["id"], True) and rec["ok"]
        if not rec["ok"]:
            details.setdefault(rec["id"], rec["detail"])
    rows = []
    for c in claims:
        held = outcome.get(c["id"])  # None: never reached (an earlier cell raised)
        rows.append(c | {"held": held, "detail": details.get(c["id"], "")})
    if error is not None:
        page = claims[0]["page"] if claims else "?"
        rows.append(
            {"id": f"{page}::<cell error>", "page": page, "line": 0, "text": "<cell error>",
             "held": False, "detail": error}
        )
    return rows


def _run_info(folder: Path) -> dict:
    info = json.loads((folder / "run.json").read_text())
    return {k: info.get(k) for k in ("profile", "seed", "preset", "numerics")}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--run", action="append", required=True, metavar="NAME=FOLDER",
                   help="a run folder of scrppl reproduce, and the name it has in the record")
    p.add_argument("--pages", nargs="*", default=None, help="pages (default: book/chapters/*.md)")
    p.add_argument("--out", type=Path, default=None, help="JSON record to write (updated if it exists)")
    p.add_argument("--cpu", default=None,
                   help="how the runs' CPU features were set (recorded; e.g. 'narrowed: AVX2')")
    p.add_argument("--timeout", type=int, default=600, help="seconds per cell")
    p.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1),
                   help="pages executed at once, each in its own kernel (default: 2, or 1 on one core)")
    p.add_argument("--require-all", action="store_true",
                   help="exit 1 when a claim fails (or a cell raises) in any given run")
    args = p.parse_args(argv)

    runs = {}
    for spec in args.run:
        name, _, folder = spec.partition("=")
        folder = Path(folder)
        if not (folder / "run.json").exists():
            p.error(f"--run {spec}: {folder} has no run.json (not a run folder of scrppl reproduce)")
        runs[name] = folder
    pages = [Path(x) for x in args.pages] if args.pages else sorted((ROOT / "book" / "chapters").glob("*.md"))

    # the kernels import NumPy before scrppl: give them the portable numerics of the scrppl commands now
    # (inherited through the environment), as scripts/build-book.sh does
    from scrppl.numerics import apply_portable_settings

    apply_portable_settings()
    results: dict[str, list[dict]] = {}
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name, folder in runs.items():

            async def one(i, path, gate, name=name, folder=folder):
                page = path.resolve().relative_to(ROOT / "book").with_suffix("").as_posix()
                nb, claims = instrument_page(path, page)
                async with gate:
                    t0 = time.time()
                    log = Path(tmp) / f"claims-{i}.jsonl"
                    got = await run_page_async(nb, claims, folder, log, args.timeout)
                bad = [r for r in got if r["held"] is not True]
                lines = [f"[claims] {name}: {page}: {len(got) - len(bad)} of {len(got)} held "
                         f"({time.time() - t0:.0f} s)"]
                lines += [f"[claims]   FAILED line {r['line']}: {r['text']}  {r['detail']}" for r in bad]
                print("\n".join(lines), flush=True)
                return got, len(bad)

            async def every_page():
                gate = asyncio.Semaphore(max(1, args.jobs))  # pages whose kernels run at once
                return await asyncio.gather(*(one(i, p, gate) for i, p in enumerate(pages)))

            done = asyncio.run(every_page())  # in the pages' order, whatever order they finish in
            results[name] = [r for got, _ in done for r in got]
            failures += sum(n for _, n in done)

    if args.out:
        record = json.loads(args.out.read_text()) if args.out.exists() else {}
        old_runs = record.get("runs", {})
        old_claims = {c["id"]: c for c in record.get("claims", [])}
        all_claims: dict[str, dict] = {}
        for rows in results.values():
            for r in rows:
                all_claims.setdefault(r["id"], {k: r[k] for k in ("id", "page", "line", "text")})
        for name, folder in runs.items():
            old_runs[name] = _run_info(folder) | {
                "cpu": args.cpu or "as is",
                "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            }
        # the claims the record keeps: those of this execution, with the old runs' outcomes where known
        out_claims = []
        for cid, c in all_claims.items():
            held_in = dict(old_claims.get(cid, {}).get("held_in", {}))
            for name, rows in results.items():
                match = [r for r in rows if r["id"] == cid]
                held_in[name] = bool(match and match[0]["held"] is True)
            held_in = {k: v for k, v in held_in.items() if k in old_runs}
            out_claims.append(c | {"held_in": held_in, "held": sum(held_in.values()),
                                   "runs": len(held_in)})
        out = {
            "what": "every assert of the book's chapters, executed against several book-profile runs "
                    "(scripts/book_claims.py): the runs it held in",
            "runs": old_runs,
            "n_claims": len(out_claims),
            "n_held_everywhere": sum(c["held"] == c["runs"] == len(old_runs) for c in out_claims),
            "claims": out_claims,
        }
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp_path = args.out.with_suffix(".json.tmp")
        tmp_path.write_text(json.dumps(out, indent=1) + "\n")
        tmp_path.replace(args.out)
        print(f"[claims] {out['n_held_everywhere']} of {out['n_claims']} claims held in all "
              f"{len(old_runs)} runs -> {args.out}")
    if failures:
        print(f"[claims] {failures} claim(s) failed", file=sys.stderr)
    return 1 if (failures and args.require_all) else 0


if __name__ == "__main__":
    sys.exit(main())
