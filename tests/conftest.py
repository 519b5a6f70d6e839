"""Test configuration shared by the whole suite.

* JAX runs on the CPU (a GPU, if present, would change float rounding and timings).
* Two host devices, so that code using ``chain_method="parallel"`` can be tested on 2-core machines.
  This must be set before JAX initialises, hence at import time here.
* PRNG keys are fixed (``key`` fixture); no test draws a seed at run time.
* Portable numerics (:mod:`scrppl.numerics`): ``import scrppl`` comes before NumPy and JAX.
* Warnings are errors (``filterwarnings = error`` in pyproject.toml); narrow exceptions are listed
  there with a comment.
* No persistent JAX compilation cache (``SCRPPL_JAX_CACHE=0``, also for the ``scrppl`` commands tests
  start): every test compiles what it runs, as on a fresh machine (tests/test_compilation_cache.py turns
  it on where it is the subject).
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("SCRPPL_JAX_CACHE", "0")

# The portable numerics of every scrppl process (scrppl.numerics), before NumPy loads: the suite then
# computes the same bytes on every x86-64 machine with AVX2.
from scrppl.numerics import apply_portable_settings  # noqa: E402, I001

apply_portable_settings()

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

SEED = 20100503  # fixed for the whole suite


@pytest.fixture
def key():
    """A fixed JAX PRNG key."""
    return jax.random.key(SEED)


@pytest.fixture
def rng():
    """A fixed NumPy generator."""
    return np.random.default_rng(SEED)
