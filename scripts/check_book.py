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

It serves ``book/_build/html`` over loopback and drives one headless Chromium per worker over the DevTools
protocol on a pipe (``--remote-debugging-pipe``: no browser driver, no port): each page is loaded once in
a reused tab, inspected by a script run in it after MathJax has typeset, and photographed; the
screenshots go to ``book/_build/screenshots/``. Exit status 1 if any check fails.

Usage: ``python scripts/check_book.py [--html book/_build/html] [--toc book/_toc.yml]``
"""

from __future__ import annotations

import argparse
import base64
import fcntl
import functools
import http.server
import json
import os
import queue
import re
import select
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

#: Run in each loaded page: what a reader would see (after MathJax has typeset, if the page has it).
INSPECT = """(async () => {
  const w = window;
  if (w.MathJax && w.MathJax.startup && w.MathJax.startup.promise) {
    try { await w.MathJax.startup.promise; } catch (e) {}
    await new Promise(r => setTimeout(r, 500));
  } else {  // no MathJax: the load event has fired (images in); wait for the fonts, then a moment
    try { await document.fonts.ready; } catch (e) {}
    await new Promise(r => setTimeout(r, 300));
  }
  const d = document;
  const main = d.querySelector("main") || d.body;
  const imgs = Array.from(main.querySelectorAll("img"));
  const text = main.innerText || "";
  const h1 = d.querySelector("h1");
  return {
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
  };
})()"""


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


def _high(fd: int) -> int:
    """``fd`` moved to the lowest free descriptor >= 10 (close-on-exec)."""
    high = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return high


class Browser:
    """One headless Chromium driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``).

    The browser reads NUL-terminated JSON commands on its descriptor 3 and writes replies and events on
    its descriptor 4; no driver and no network port. One tab is reused for every page: load it, run
    :data:`INSPECT` in it, take its screenshot.
    """

    def __init__(self, path: str, profile: str, timeout: float = 120.0):
        # the pipes at descriptors >= 10, so that bash's "3<&N 4>&M" cannot overwrite one by the other
        # (bash, not sh: dash reads only one-digit descriptors in a redirection)
        to_browser, from_us, from_browser, to_us = (_high(fd) for fd in (*os.pipe(), *os.pipe()))
        self.timeout = timeout
        self.proc = subprocess.Popen(
            ["bash", "-c", f'exec "$0" "$@" 3<&{to_browser} 4>&{to_us}', path, *CHROMIUM_FLAGS,
             f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"],
            pass_fds=(to_browser, to_us),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
        for fd in (to_browser, to_us):
            os.close(fd)
        self._out, self._in = from_us, from_browser
        self._buf = b""
        self._id = 0
        self.events: list[dict] = []
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        self.call("Page.enable", session=True)
        self.call("Network.enable", session=True)  # for the status of each page's document
        self.call(
            "Emulation.setDeviceMetricsOverride",
            {"width": 1280, "height": 2400, "deviceScaleFactor": 1, "mobile": False},
            session=True,
        )

    def _read(self, deadline: float) -> dict:
        while b"\0" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._in], [], [], left)[0]:
                raise TimeoutError("the browser did not answer in time")
            chunk = os.read(self._in, 1 << 20)
            if not chunk:
                raise RuntimeError("the browser closed its DevTools pipe")
            self._buf += chunk
        message, self._buf = self._buf.split(b"\0", 1)
        return json.loads(message)

    def call(self, method: str, params: dict | None = None, *, session: bool = False) -> dict:
        """Send one command and return its result (events that arrive meanwhile are kept)."""
        self._id += 1
        message = {"id": self._id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = self.session
        os.write(self._out, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._read(deadline)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            self.events.append(reply)

    def wait_for(self, event: str) -> None:
        """Wait for an event of the tab (one already kept counts)."""
        deadline = time.monotonic() + self.timeout
        while not any(
            e.get("method") == event and e.get("sessionId") == self.session for e in self.events
        ):
            self.events.append(self._read(deadline))

    def inspect(self, url: str, shot: Path) -> dict:
        """Load ``url``, return :data:`INSPECT`'s findings and write a screenshot of the page to ``shot``."""
        try:
            self.events.clear()
            nav = self.call("Page.navigate", {"url": url}, session=True)
            if nav.get("errorText"):
                return {"probe_failed": f"{url} did not load: {nav['errorText']}"}
            self.wait_for("Page.loadEventFired")
            status = next(
                (
                    e["params"]["response"]["status"]
                    for e in self.events
                    if e.get("method") == "Network.responseReceived"
                    and e["params"].get("type") == "Document"
                    and e["params"]["response"]["url"] == url
                ),
                None,
            )
            if status != 200:
                return {"probe_failed": f"{url} answered HTTP {status}"}
            found = self.call(
                "Runtime.evaluate",
                {"expression": INSPECT, "awaitPromise": True, "returnByValue": True},
                session=True,
            )
            if "exceptionDetails" in found:
                return {"probe_failed": str(found["exceptionDetails"])[:300]}
            png = self.call("Page.captureScreenshot", {"format": "png"}, session=True)["data"]
            shot.write_bytes(base64.b64decode(png))
            return found["result"]["value"]
        except (TimeoutError, RuntimeError, OSError) as err:  # OSError: the browser's pipe broke
            return {"probe_failed": f"{type(err).__name__}: {err}"}

    def close(self) -> None:
        try:
            self.call("Browser.close")
        except (TimeoutError, RuntimeError, OSError):
            pass
        for fd in (self._out, self._in):
            os.close(fd)
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


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
    args.screenshots.mkdir(parents=True, exist_ok=True)
    server, port = serve(args.html)
    summary = {}
    pages = toc_pages(args.toc)

    def check_page(page: str, tab: Browser) -> tuple[str, list[str], dict, dict, Path]:
        shot = args.screenshots / f"{page.replace('/', '-')}.png"
        r = tab.inspect(f"http://127.0.0.1:{port}/{page}.html", shot)
        probs = problems_of(page, r)
        if page.startswith(args.require_math) and not r.get("mathjax"):
            probs.append("no typeset math on a chapter page")
        download_problems, downloads = check_downloads(args.html, page, port)
        probs += download_problems
        return page, probs, r, downloads, shot

    browsers: list[Browser] = []
    tmp = tempfile.TemporaryDirectory()
    try:
        # pages in parallel, one browser (with its own profile: a profile is locked by its browser) per
        # worker, started here in the main thread
        with ThreadPoolExecutor(args.workers) as pool:
            idle = queue.Queue()
            for i in range(args.workers):
                browsers.append(Browser(browser, str(Path(tmp.name) / f"profile-{i}")))
                idle.put(browsers[-1])

            def job(page: str):
                tab = idle.get()
                try:
                    return check_page(page, tab)
                finally:
                    idle.put(tab)

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
        for b in browsers:
            b.close()
        tmp.cleanup()
        server.shutdown()
        server.server_close()
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
