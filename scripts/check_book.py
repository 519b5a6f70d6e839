"""Open every page of the built book in headless Chromium and check it as a reader would see it.

For each chapter (every page listed in ``book/_toc.yml``) the check asserts that:

* the page has its title (a non-empty ``<h1>``);
* every image in the page loaded (``naturalWidth > 0``);
* math is typeset: MathJax output elements are present and no raw ``\\(`` / ``$$`` delimiters remain;
* no cell shows an error, a traceback or stderr output, and Sphinx left no error message in the page;
* the page loads no remote script, stylesheet or font (checked on the HTML files);
* downloads: every chapter page (``chapters/``) offers its notebook and every exercise page
  (``exercises/``) its notebook and its student copy in the download menu, and each link, fetched from
  the loopback server, is a valid notebook (the student copy: no outputs, an answer cell to write;
  ``book/_ext/scrppl_downloads.py`` writes them).

It serves ``book/_build/html`` over loopback, loads each page inside a same-origin ``<iframe>`` of a small
probe page (so that plain ``chromium --dump-dom`` can read the loaded page's DOM, with no browser driver),
and writes a screenshot of every page to ``book/_build/screenshots/``. Exit status 1 if any check fails.

Usage: ``python scripts/check_book.py [--html book/_build/html] [--toc book/_toc.yml]``
"""

from __future__ import annotations

import argparse
import functools
import http.server
import json
import os
import queue
import re
import shutil
import subprocess
import sys
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

PROBE = """<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>probe</title></head>
<body><pre id="result">pending</pre>
<script>
const page = new URLSearchParams(location.search).get("page");
const frame = document.createElement("iframe");
frame.style.width = "1280px"; frame.style.height = "1200px";
document.body.appendChild(frame);
function report(obj) { document.getElementById("result").textContent = "RESULT:" + JSON.stringify(obj); }
function inspect() {
  const d = frame.contentDocument;
  const main = d.querySelector("main") || d.body;
  const imgs = Array.from(main.querySelectorAll("img"));
  const text = main.innerText || "";
  const h1 = d.querySelector("h1");
  report({
    title: h1 ? h1.innerText.replace(/[#¶]/g, "").trim() : "",
    doc_title: d.title,
    images: imgs.length,
    broken_images: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.getAttribute("src")),
    math_elements: main.querySelectorAll(".math, span.math, div.math").length,
    mathjax: main.querySelectorAll("mjx-container").length,
    raw_math: (text.match(/\\\\\\(|\\\\\\[|\\$\\$/g) || []).length,
    stderr: main.querySelectorAll(".output.stderr, .stderr").length,
    tracebacks: main.querySelectorAll(".output.traceback, .traceback").length + (text.includes("Traceback (most recent call last)") ? 1 : 0),
    errors: Array.from(main.querySelectorAll(".system-message, .problematic")).map(e => e.innerText.slice(0, 200)),
    chars: text.length,
  });
}
frame.onload = () => {
  const w = frame.contentWindow;
  const done = () => setTimeout(inspect, 500);
  if (w.MathJax && w.MathJax.startup && w.MathJax.startup.promise) {
    w.MathJax.startup.promise.then(done, done);
  } else { setTimeout(inspect, 3000); }
};
frame.src = page;
</script></body></html>
"""

REMOTE = re.compile(r"""(?:src|href)=["']https?://[^"']+\.(?:js|css|woff2?|ttf)(?:\?[^"']*)?["']""")
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
]


def toc_pages(toc: Path) -> list[str]:
    """Every page named in a Jupyter Book 1.x ``_toc.yml`` (root first), without suffix."""
    data = yaml.safe_load(toc.read_text())
    pages = [data["root"]]

    def walk(entries):
        for e in entries or []:
            if "file" in e:
                pages.append(e["file"])
            walk(e.get("sections"))
            walk(e.get("chapters"))

    for part in data.get("parts", []):
        walk(part.get("chapters"))
    walk(data.get("chapters"))
    walk(data.get("sections"))
    return pages


def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    raise SystemExit(
        "check_book: no Chromium found; install it with `apt-get install -y chromium` "
        "(scripts/build-book.sh does this when it can)"
    )


def serve(html: Path) -> tuple[http.server.ThreadingHTTPServer, int]:
    handler = functools.partial(QuietHandler, directory=str(html))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, server.server_address[1]


class QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # noqa: D102
        pass


def probe(browser: str, url: str, profile: str) -> dict:
    cmd = [
        browser,
        *CHROMIUM_FLAGS,
        f"--user-data-dir={profile}",
        "--virtual-time-budget=30000",
        "--dump-dom",
        url,
    ]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout
    m = re.search(r"RESULT:(\{.*?\})</pre>", out, re.S)
    if not m:
        return {"probe_failed": out[-300:]}
    import html as _html

    return json.loads(_html.unescape(m.group(1)))


def screenshot(browser: str, url: str, path: Path, profile: str) -> None:
    cmd = [
        browser,
        *CHROMIUM_FLAGS,
        f"--user-data-dir={profile}",
        "--window-size=1280,2400",
        "--virtual-time-budget=20000",
        f"--screenshot={path}",
        url,
    ]
    subprocess.run(cmd, capture_output=True, timeout=120)


#: The download menu's links (sphinx-book-theme renders each as ``<a href=... class="btn ... btn-<label>``).
DOWNLOAD_LINK = re.compile(
    r"""<a href="(?P<href>[^"]+)"[^>]*?class="[^"]*\bbtn-(?P<label>download-(?:notebook|student)-button)\b"""
)
#: Which downloads a page must offer, by the start of its path.
REQUIRED_DOWNLOADS = {
    "chapters/": ("download-notebook-button",),
    "exercises/": ("download-notebook-button", "download-student-button"),
}


def download_links(html: Path, page: str) -> dict[str, str]:
    """``{label: href}`` of a built page's notebook downloads (hrefs relative to the page)."""
    path = html / f"{page}.html"
    if not path.exists():
        return {}
    text = path.read_text(errors="replace")
    return {m.group("label"): m.group("href") for m in DOWNLOAD_LINK.finditer(text)}


def check_downloads(html: Path, page: str, port: int) -> tuple[list[str], dict]:
    """Fetch the page's notebook downloads over loopback; the problems, and what was fetched."""
    import urllib.parse
    import urllib.request

    import nbformat

    required = next((v for k, v in REQUIRED_DOWNLOADS.items() if page.startswith(k)), ())
    links = download_links(html, page)
    problems = [
        f"no {label.removesuffix('-button')} link" for label in required if label not in links
    ]
    fetched = {}
    for label, href in links.items():
        url = urllib.parse.urljoin(f"http://127.0.0.1:{port}/{page}.html", href)
        try:
            with urllib.request.urlopen(url, timeout=30) as response:
                body = response.read()
            nb = nbformat.reads(body.decode("utf-8"), as_version=4)
            nbformat.validate(nb)
        except Exception as err:  # noqa: BLE001 - reported as the page's problem
            problems.append(f"{label} {href}: not a valid notebook ({type(err).__name__}: {err})")
            continue
        code = [c for c in nb.cells if c.cell_type == "code"]
        if not code:
            problems.append(f"{label} {href}: no code cell")
        if label == "download-student-button":
            if any(c.get("outputs") for c in code):
                problems.append(f"{label} {href}: the student copy has outputs")
            if not any("answer" in c.get("metadata", {}).get("tags", []) for c in code):
                problems.append(f"{label} {href}: the student copy has no answer cell")
        fetched[label] = {"href": href, "bytes": len(body), "cells": len(nb.cells)}
    return problems, fetched


def problems_of(page: str, r: dict) -> list[str]:
    if "probe_failed" in r:
        return [f"the page could not be inspected: {r['probe_failed']!r}"]
    out = []
    if not r["title"]:
        out.append("no title (<h1>)")
    if r["broken_images"]:
        out.append(f"images that did not load: {r['broken_images']}")
    if r["math_elements"] and not r["mathjax"]:
        out.append(f"{r['math_elements']} math elements but no MathJax output")
    if r["raw_math"]:
        out.append(f"{r['raw_math']} raw math delimiters in the text")
    if r["stderr"]:
        out.append(f"{r['stderr']} cells show stderr output")
    if r["tracebacks"]:
        out.append(f"{r['tracebacks']} tracebacks")
    if r["errors"]:
        out.append(f"Sphinx error messages: {r['errors']}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--html", type=Path, default=Path("book/_build/html"))
    parser.add_argument("--toc", type=Path, default=Path("book/_toc.yml"))
    parser.add_argument("--screenshots", type=Path, default=Path("book/_build/screenshots"))
    parser.add_argument(
        "--require-math",
        default="chapters/",
        help="pages whose path starts with this must contain typeset math (default: chapters/)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=int(os.environ.get("BOOK_JOBS", min(2, os.cpu_count() or 1))),
        help="pages checked at once, one browser each (default: $BOOK_JOBS, else 2, or 1 on one core)",
    )
    args = parser.parse_args(argv)
    if not (args.html / "index.html").exists():
        print(f"check_book: {args.html}/index.html not found: build the book first (make book)")
        return 1
    failures: dict[str, list[str]] = {}

    remote = []
    for f in sorted(args.html.rglob("*.html")):
        for m in REMOTE.finditer(f.read_text(errors="replace")):
            remote.append(f"{f.relative_to(args.html)}: {m.group(0)}")
    if remote:
        failures["(all pages)"] = [f"remote assets: {remote[:10]}"]

    browser = chromium()
    (args.html / "_probe.html").write_text(PROBE)
    args.screenshots.mkdir(parents=True, exist_ok=True)
    server, port = serve(args.html)
    summary = {}
    pages = toc_pages(args.toc)

    def check_page(page: str, profile: str) -> tuple[str, list[str], dict, dict, Path]:
        url = f"http://127.0.0.1:{port}/{page}.html"
        r = probe(browser, f"http://127.0.0.1:{port}/_probe.html?page=/{page}.html", profile)
        probs = problems_of(page, r)
        if page.startswith(args.require_math) and not r.get("mathjax"):
            probs.append("no typeset math on a chapter page")
        download_problems, downloads = check_downloads(args.html, page, port)
        probs += download_problems
        shot = args.screenshots / f"{page.replace('/', '-')}.png"
        screenshot(browser, url, shot, profile)
        return page, probs, r, downloads, shot

    try:
        # pages in parallel, one Chromium profile per worker (a profile is locked by the browser using it)
        with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(args.workers) as pool:
            profiles = queue.Queue()
            for i in range(args.workers):
                profiles.put(str(Path(tmp) / f"profile-{i}"))

            def job(page: str):
                profile = profiles.get()
                try:
                    return check_page(page, profile)
                finally:
                    profiles.put(profile)

            for page, probs, r, downloads, shot in pool.map(job, pages):  # in the table's order
                if probs:
                    failures[page] = probs
                summary[page] = {k: r.get(k) for k in ("title", "images", "mathjax", "chars")}
                if downloads:
                    summary[page]["downloads"] = downloads
                status = "ok" if not probs else "FAIL"
                offered = "".join(
                    f", {label.split('-')[1]} .ipynb {d['bytes'] // 1024} kB"
                    for label, d in downloads.items()
                )
                print(
                    f"[check-book] {status:4} {page}: '{r.get('title', '')}', {r.get('images', 0)} images, "
                    f"{r.get('mathjax', 0)} typeset formulas{offered} -> {shot}",
                    flush=True,
                )
    finally:
        server.shutdown()
        (args.html / "_probe.html").unlink(missing_ok=True)
    (args.screenshots / "check.json").write_text(json.dumps(summary, indent=2))
    if failures:
        for page, probs in failures.items():
            for p in probs:
                print(f"[check-book] {page}: {p}", file=sys.stderr)
        return 1
    print(f"[check-book] all {len(summary)} pages pass")
    return 0


if __name__ == "__main__":
    sys.exit(main())
