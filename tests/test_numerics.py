"""Portable numerics (scrppl.numerics) and the run settings that make a run folder stale."""

import json
import platform
import subprocess
import sys

import pytest

from scrppl import numerics
from scrppl.results import run_settings_changed, write_run_info

x86 = platform.machine().lower() in ("x86_64", "amd64")


@pytest.mark.skipif(not x86, reason="the portable settings are for x86-64")
def test_portable_settings_fill_what_is_missing_and_keep_what_is_set():
    env = {"OPENBLAS_CORETYPE": "SkylakeX", "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    changed = numerics.apply_portable_settings(env)
    assert env["OPENBLAS_CORETYPE"] == "SkylakeX"  # the user's choice stays
    assert "OPENBLAS_CORETYPE" not in changed
    assert env["NPY_DISABLE_CPU_FEATURES"] == numerics.PORTABLE_ENV["NPY_DISABLE_CPU_FEATURES"]
    # the ISA limit is appended to the flags already there, once
    assert env["XLA_FLAGS"].split() == [
        "--xla_force_host_platform_device_count=2",
        numerics.XLA_PORTABLE_FLAG,
    ]
    assert numerics.apply_portable_settings(env) == {}
    # a maximum ISA named by the user is kept
    env = {"XLA_FLAGS": "--xla_cpu_max_isa=SSE4_2"}
    numerics.apply_portable_settings(env)
    assert env["XLA_FLAGS"] == "--xla_cpu_max_isa=SSE4_2"


def test_native_cpu_turns_the_settings_off(monkeypatch):
    monkeypatch.setenv(numerics.NATIVE_ENV, "1")
    env = {numerics.NATIVE_ENV: "1"}
    assert numerics.apply_portable_settings(env) == {} and set(env) == {numerics.NATIVE_ENV}
    assert numerics.mode() == "native"
    assert numerics.shell_exports() == ""


@pytest.mark.skipif(not x86, reason="the portable settings are for x86-64")
def test_a_fresh_process_importing_scrppl_first_runs_numpy_without_avx512():
    """``import scrppl`` before NumPy: NumPy's AVX-512 loops are off, every variable is set."""
    code = (
        "import json, scrppl, numpy; from scrppl import numerics; "
        "print(json.dumps(numerics.settings()))"
    )
    env = {"PATH": "/usr/bin:/bin", "HOME": "/tmp"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    s = json.loads(out.stdout)
    assert s["portable"] and s["mode"] == "portable" and s["numpy_avx512"] is False, s
    # ... and NumPy's exp then rounds as an AVX2 machine's does: the same bits as with the variable set
    # by hand before NumPy loads
    probe = "import numpy as np; print(np.exp(np.linspace(-3, 3, 1001)).tobytes().hex()[:4000])"
    ours = subprocess.run(
        [sys.executable, "-c", "import scrppl; " + probe], capture_output=True, text=True, env=env
    )
    by_hand = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        env=env | {"NPY_DISABLE_CPU_FEATURES": numerics.PORTABLE_ENV["NPY_DISABLE_CPU_FEATURES"]},
    )
    assert ours.stdout and ours.stdout == by_hand.stdout


def test_run_settings_changed_names_what_differs(tmp_path):
    assert run_settings_changed(tmp_path, seed=0) == []  # no run.json yet
    write_run_info(tmp_path, profile="book", seed=0, dataset_root=tmp_path, preset="clean")
    info = json.loads((tmp_path / "run.json").read_text())
    assert info["numerics"] == numerics.mode()
    same = dict(profile="book", seed=0, preset="clean", numerics=numerics.mode())
    assert run_settings_changed(tmp_path, **same) == []
    assert run_settings_changed(tmp_path, **(same | {"seed": 1})) == ["seed"]
    other = "native" if numerics.mode() == "portable" else "portable"
    assert run_settings_changed(tmp_path, **(same | {"numerics": other, "profile": "full"})) == [
        "profile",
        "numerics",
    ]
    (tmp_path / "run.json").write_text("{not json")
    assert run_settings_changed(tmp_path, seed=0) == ["run.json (unreadable)"]


INTEL_AVX512 = "vendor_id\t: GenuineIntel\nflags\t\t: fpu sse2 avx avx2 fma avx512f avx512dq\n"
AMD_AVX512 = "vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma avx512f avx512_bf16\n"
AMD_AVX2 = "vendor_id\t: AuthenticAMD\nflags\t\t: fpu sse2 avx avx2 fma\n"


def test_openblas_is_pinned_except_on_amd_with_avx512():
    """The Haswell DGEMM kernel kills the process on an AMD CPU with AVX-512: no pin there, the rest kept."""
    assert numerics.portable_env(INTEL_AVX512) == numerics.PORTABLE_ENV
    assert numerics.portable_env(AMD_AVX2) == numerics.PORTABLE_ENV
    amd = numerics.portable_env(AMD_AVX512)
    assert "OPENBLAS_CORETYPE" not in amd
    assert amd == {k: v for k, v in numerics.PORTABLE_ENV.items() if k != "OPENBLAS_CORETYPE"}


@pytest.mark.skipif(not x86, reason="the portable settings are for x86-64")
def test_matrix_products_that_crashed_an_amd_epyc_run_under_the_portable_settings():
    """On an AMD EPYC with AVX-512, ``OPENBLAS_CORETYPE=Haswell`` made these products die of SIGSEGV.

    Run in a fresh process with ``import scrppl`` first (its settings), the shapes of the K-way stage's
    bootstrap that crashed; each product is checked against a sum written out in NumPy.
    """
    code = (
        "import scrppl, numpy as np\n"
        "rng = np.random.default_rng(0)\n"
        "for n in (400, 480, 800):\n"
        "    c, f = rng.random((64, n)), rng.random((n, 9))\n"
        "    for _ in range(20):\n"
        "        r = c @ f\n"
        "    assert np.allclose(r, (c[:, :, None] * f[None]).sum(1))\n"
        "print('ok')\n"
    )
    env = {"PATH": "/usr/bin:/bin", "HOME": "/tmp"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0 and out.stdout.strip() == "ok", (out.returncode, out.stderr[-2000:])
