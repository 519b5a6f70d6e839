"""The book's page check (``scripts/check_book.py``) on hand-made pages in a real headless Chromium.

The check drives the browser over the DevTools protocol on a pipe; here it must find what a reader would
see: a page with its title, image and typeset-free text passes, and a page with a broken image, stderr
output, a traceback and a Sphinx error message fails with each named. Skipped where no Chromium is
installed (``.ci/run`` and ``make book`` install it).
"""

import contextlib
import importlib.util
import shutil
import socket
import struct
import zlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_book", ROOT / "scripts" / "check_book.py")
check_book = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check_book)

pytestmark = pytest.mark.skipif(
    not any(shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")),
    reason="no Chromium installed",
)


def _png(width: int, height: int) -> bytes:
    """A grey PNG, written by hand (no image library)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    rows = b"".join(b"\0" + b"\x80" * width for _ in range(height))
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows))
        + chunk(b"IEND", b"")
    )


GOOD = """<!DOCTYPE html><html><head><title>Good</title></head><body><main>
<h1>A good page<a class="headerlink" href="#">#</a></h1><p>Some text.</p><img src="grey.png">
</main></body></html>"""

BAD = """<!DOCTYPE html><html><head><title>Bad</title></head><body><main>
<h1>A bad page</h1><img src="missing.png">
<div class="output stderr"><pre>RuntimeWarning: overflow</pre></div>
<pre>Traceback (most recent call last):
  File "x.py", line 1</pre>
<div class="system-message">Unknown directive type "figur".</div>
</main></body></html>"""


@contextlib.contextmanager
def served(tmp_path, pages: dict[str, str | bytes]):
    """A loopback server of ``pages`` (name -> content) and a browser: ``(tab, port)``, both closed after."""
    html = tmp_path / "html"
    html.mkdir()
    for name, content in pages.items():
        path = html / name
        path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    server, port = check_book.serve(html)
    tab = check_book.Browser(check_book.chromium(), str(tmp_path / "profile"), timeout=60)
    try:
        yield tab, port
    finally:
        tab.close()
        server.shutdown()
        server.server_close()


def test_browser_check_passes_a_good_page_and_names_each_fault_of_a_bad_one(tmp_path):
    pages = {"grey.png": _png(40, 30), "good.html": GOOD, "bad.html": BAD}
    with served(tmp_path, pages) as (tab, port):
        good = tab.inspect(f"http://127.0.0.1:{port}/good.html", tmp_path / "good.png")
        bad = tab.inspect(f"http://127.0.0.1:{port}/bad.html", tmp_path / "bad.png")
    assert good["title"] == "A good page" and good["images"] == 1
    assert check_book.problems_of("good", good) == []
    problems = " | ".join(check_book.problems_of("bad", bad))
    assert "missing.png" in problems
    assert "1 cells show stderr output" in problems
    assert "tracebacks" in problems
    assert "figur" in problems
    # the screenshots are PNGs of the browser's 1280-pixel-wide window
    for name in ("good.png", "bad.png"):
        data = (tmp_path / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        assert struct.unpack(">I", data[16:20])[0] == 1280
    assert tab.proc.poll() is not None  # the browser is gone


def test_a_page_that_does_not_load_is_reported_not_hung(tmp_path):
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    with served(tmp_path, {}) as (tab, port):
        missing = tab.inspect(f"http://127.0.0.1:{port}/missing.html", tmp_path / "x.png")
        refused = tab.inspect(f"http://127.0.0.1:{closed}/nothing.html", tmp_path / "y.png")
    # the server's 404 page and Chromium's error page both have an <h1>: the status must fail them
    assert "HTTP 404" in check_book.problems_of("missing", missing)[0]
    assert "ERR_CONNECTION_REFUSED" in check_book.problems_of("nothing", refused)[0]
