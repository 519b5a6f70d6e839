"""Portable numerics: the same bytes on every x86-64 machine with AVX2, whatever else its CPU has.

NumPy, OpenBLAS, XLA (under JAX), OpenCV and Mesa's llvmpipe renderer each pick the fastest code for the
CPU they find. On a machine with AVX-512 that code rounds differently in the last bit from the code a
machine with only AVX2 runs: NumPy's ``exp``, ``log`` and ``power`` do (measured: the float32 ``x ** g``
of the synthetic camera model and even ``np.exp`` of a scalar differ), and so may OpenBLAS's SkylakeX
kernels. One rounded grey level changes a JPEG, a detector score, an MCMC trajectory, and from there
every number of a run (:doc:`the book's note on reproducibility <../reproducibility>`).

:func:`apply_portable_settings` asks each of them for the code an AVX2 machine (x86-64-v3) runs, through
the environment variables they read when they load:

============================  ============================================  ==========================
variable                      value                                         read by
============================  ============================================  ==========================
``NPY_DISABLE_CPU_FEATURES``  ``X86_V4 AVX512_ICL AVX512_SPR``              NumPy, at import
``OPENBLAS_CORETYPE``         ``Haswell`` (not on AMD with AVX-512)         OpenBLAS, at load
``XLA_FLAGS``                 ``--xla_cpu_max_isa=AVX2`` (appended)         XLA, at JAX's first use
``OPENCV_CPU_DISABLE``        the AVX-512 dispatch targets                  OpenCV, at import
``LP_NATIVE_VECTOR_WIDTH``    ``256``                                       llvmpipe, at first render
============================  ============================================  ==========================

One exception, by CPU: OpenBLAS's Haswell matrix-product kernel overwrites its own stack on an AMD CPU
with AVX-512 (measured on an AMD EPYC with the locked OpenBLAS 0.3.34: a ``(64, 480) @ (480, 9)`` product
kills the process), so there :func:`portable_env` leaves OpenBLAS to choose its kernels, and its matrix
products round as that CPU's own code does. On such a machine the other four settings still hold.

``import scrppl`` calls it before it imports NumPy, so every ``scrppl`` command and every process it
starts (they inherit the environment) computes the same bytes on an AVX-512 machine as on an AVX2 one. A
variable already set is left alone, and ``SCRPPL_NATIVE_CPU=1`` turns the whole thing off (each library
then chooses for itself: faster on some machines, and the same numbers only up to rounding). In a
Python session that imported NumPy *before* scrppl, NumPy's choice was already made: :func:`settings`
says so.

What stays machine-dependent: other instruction sets (Arm), and machines without AVX2 and FMA, compute
their own roundings; results there agree with the recorded ones statistically, not bit for bit. So,
measured, do other CPU models with these settings: NUTS fits remade on an Intel Xeon gave other draws
than on an AMD EPYC (both with AVX-512), while closed-form fits were identical.
"""

from __future__ import annotations

import os
import platform
import sys

__all__ = [
    "PORTABLE_ENV",
    "portable_env",
    "XLA_PORTABLE_FLAG",
    "NATIVE_ENV",
    "apply_portable_settings",
    "mode",
    "settings",
    "shell_exports",
]

#: Environment variables that pin each library to the code of an AVX2 (x86-64-v3) machine.
PORTABLE_ENV: dict[str, str] = {
    # NumPy's dispatch targets above X86_V3 in the locked NumPy (numpy._core._multiarray_umath.__cpu_dispatch__)
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
    "OPENBLAS_CORETYPE": "Haswell",
    "OPENCV_CPU_DISABLE": "AVX512-SKX",  # the AVX-512 dispatch target of the locked OpenCV (cv2.getCPUFeaturesLine())
    "LP_NATIVE_VECTOR_WIDTH": "256",
}
#: Kernels OpenBLAS must not be pinned to on some CPUs: see :func:`portable_env`.
_OPENBLAS_UNSAFE = "OPENBLAS_CORETYPE"


def _cpu_vendor_and_avx512(cpuinfo: str | None = None) -> tuple[str, bool]:
    """The CPU's vendor id (``GenuineIntel``, ``AuthenticAMD``, or ``""``) and whether it has AVX-512F.

    Read from ``/proc/cpuinfo`` (Linux), else from :func:`platform.processor` (no AVX-512 answer there).
    """
    if cpuinfo is None:
        try:
            with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
                cpuinfo = f.read(65536)
        except OSError:
            cpuinfo = ""
    vendor, flags = "", set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "vendor_id" and not vendor:
            vendor = value.strip()
        elif key == "flags" and not flags:
            flags = set(value.split())
        if vendor and flags:
            break
    if not vendor:
        proc = platform.processor()
        vendor = next((v for v in ("GenuineIntel", "AuthenticAMD") if v in proc), "")
    return vendor, "avx512f" in flags


def portable_env(cpuinfo: str | None = None) -> dict[str, str]:
    """:data:`PORTABLE_ENV` for this machine's CPU (or the ``/proc/cpuinfo`` text given).

    On an AMD CPU with AVX-512 it leaves out ``OPENBLAS_CORETYPE``: OpenBLAS's Haswell (and Zen) DGEMM
    kernel overwrites its stack there and the process dies of a segmentation fault (measured on an AMD
    EPYC with the locked OpenBLAS; ``tests/test_numerics.py`` runs the product that crashed). OpenBLAS then
    picks its own kernels for that CPU; every other setting stays.
    """
    env = dict(PORTABLE_ENV)
    vendor, avx512 = _cpu_vendor_and_avx512(cpuinfo)
    if vendor == "AuthenticAMD" and avx512:
        env.pop(_OPENBLAS_UNSAFE)
    return env


#: Appended to ``XLA_FLAGS`` (unless it already names a maximum ISA).
XLA_PORTABLE_FLAG = "--xla_cpu_max_isa=AVX2"
#: Set to 1 to let every library choose the code for this CPU.
NATIVE_ENV = "SCRPPL_NATIVE_CPU"


def _wanted() -> bool:
    return mode() == "portable"


def mode() -> str:
    """``"portable"`` (the default on x86-64) or ``"native"`` (``SCRPPL_NATIVE_CPU=1``, or another CPU).

    What the environment asks for; :func:`settings` says whether this process got it. Run folders and
    dataset folders are named and recorded by it (``run.json``'s ``numerics``).
    """
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return "native"
    return "portable" if os.environ.get(NATIVE_ENV, "") in ("", "0") else "native"


def apply_portable_settings(environ: dict | None = None) -> dict[str, str]:
    """Set the portable-numerics variables that are not set yet; return the ones this call set.

    Parameters
    ----------
    environ
        The environment to change (default ``os.environ``; a dict for a child process's environment).

    Returns
    -------
    dict
        The variables set by this call (empty on a non-x86 machine or with ``SCRPPL_NATIVE_CPU=1``).
    """
    env = os.environ if environ is None else environ
    if environ is None and not _wanted():
        return {}
    if environ is not None and (
        platform.machine().lower() not in ("x86_64", "amd64")
        or env.get(NATIVE_ENV, "") not in ("", "0")
    ):
        return {}
    changed = {}
    for name, value in portable_env().items():
        if name not in env:
            env[name] = changed[name] = value
    flags = env.get("XLA_FLAGS", "")
    if "--xla_cpu_max_isa" not in flags:
        env["XLA_FLAGS"] = changed["XLA_FLAGS"] = f"{flags} {XLA_PORTABLE_FLAG}".strip()
    return changed


def settings() -> dict:
    """What is in effect in this process: each variable, and whether NumPy honoured its setting.

    Returns
    -------
    dict
        ``{"mode": str, "portable": bool, "machine": str, "env": {name: value or None},
        "numpy_avx512": bool | None}``; ``mode`` is :func:`mode`;
        ``numpy_avx512`` is whether NumPy runs its AVX-512 loops (``None`` before NumPy is imported or on
        a machine without them). ``portable`` is true when every variable has its portable value and NumPy
        does not run AVX-512 code.
    """
    env = {name: os.environ.get(name) for name in (*PORTABLE_ENV, "XLA_FLAGS", NATIVE_ENV)}
    numpy_avx512 = None
    if "numpy" in sys.modules:
        from numpy._core._multiarray_umath import __cpu_features__ as features

        numpy_avx512 = bool(features.get("X86_V4") or features.get("AVX512_SKX"))
    portable = (
        all(os.environ.get(k) == v for k, v in portable_env().items())
        and XLA_PORTABLE_FLAG in (env["XLA_FLAGS"] or "")
        and not numpy_avx512
    )
    return {
        "mode": mode(),
        "portable": portable,
        "machine": platform.machine(),
        "env": env,
        "numpy_avx512": numpy_avx512,
    }


def shell_exports() -> str:
    """The portable settings as ``export NAME=value`` lines for a shell (empty when :func:`mode` is native).

    ``scripts/build-book.sh`` evaluates them so that the book's Jupyter kernels, which import NumPy before
    scrppl, compute with the same code as the ``scrppl`` commands.
    """
    import shlex

    if mode() != "portable":
        return ""
    env = dict(os.environ)  # ``import scrppl`` has applied them already, keeping any set before
    apply_portable_settings(env)
    return "\n".join(f"export {k}={shlex.quote(env[k])}" for k in (*portable_env(), "XLA_FLAGS"))
