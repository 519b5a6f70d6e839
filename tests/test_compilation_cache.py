"""The persistent JAX compilation cache of the ``scrppl`` commands and the book (scrppl._io).

Each check runs the README's library example (a filter update and the sampled planner) in a fresh Python
process, the way a ``scrppl`` command starts: :func:`scrppl._io.use_compilation_cache` before JAX loads.
A run that compiles, a run that reads every program from the cache, a run with a corrupt cache (what a
process sees when another one is still writing an entry) and a run without the cache print the same
bytes; the corrupt cache is recompiled without a word on stderr.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import re, sys
from pathlib import Path
from scrppl._io import use_compilation_cache
print("cache", use_compilation_cache())
import numpy as np
text = Path(sys.argv[1]).read_text()
block = re.search(r"## Using the library\n\n```python\n(.*?)```", text, re.S).group(1)
env = {}
exec(compile(block, "README.md", "exec"), env)
print("scores", np.asarray(env["scores"]).tobytes().hex())
print("p(o | f)", np.asarray(env["belief"].class_marginal(env["b"])).tobytes().hex())
"""


def _run(tmp_path, **extra):
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("SCRPPL_JAX_CACHE", "JAX_COMPILATION_CACHE_DIR")
    }
    env.update(SCRPPL_CACHE=str(tmp_path / "cache"), **extra)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(ROOT / "README.md")],
        env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    return out.stdout, out.stderr


@pytest.mark.slow  # four fresh Python processes, each compiling the README's example
def test_cached_programs_give_the_same_bytes_and_a_corrupt_cache_is_recompiled_silently(tmp_path):
    first, _ = _run(tmp_path)
    assert first.startswith("cache True")
    cache = tmp_path / "cache" / "jax-compilation"
    entries = sorted(cache.glob("*-cache"))
    assert entries, "the first run kept no compiled program"
    second, _ = _run(tmp_path)
    assert second == first
    assert sorted(cache.glob("*-cache")) == entries  # everything came from the cache
    for path in entries:  # half-written entries, as another process would leave them mid-write
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    third, err = _run(tmp_path)
    assert third == first
    assert "persistent compilation cache" not in err
    (tmp_path / "off").mkdir()
    off, _ = _run(tmp_path / "off", SCRPPL_JAX_CACHE="0")
    assert off.replace("cache False", "cache True") == first
    assert not (tmp_path / "off" / "cache" / "jax-compilation").exists()
