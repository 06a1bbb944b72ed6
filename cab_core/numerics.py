"""The numeric settings that decide an attempt's physics, the same on every machine.

The same code, seed and package versions gave a different verdict on another CPU (issue 14: one
task's oracle on one simulator backend). Measured here (AMD EPYC, AVX2): numpy's OpenBLAS picks
its kernels by CPU at load time (``Zen`` here; ``SkylakeX`` with AVX-512 on a recent Intel Xeon,
``Haswell``, ...), and kernels differ in the order they sum in: the same oracle attempt with
``OPENBLAS_CORETYPE=Zen`` and ``=Prescott`` gives different privileged snapshots (59 and 60 calls),
because contact-rich physics amplifies the last bit of a planned trajectory. numpy's own ufuncs
dispatch on CPU features too (AVX-512 variants of the transcendental functions among them), and
OpenBLAS's result may depend on its thread count.

So an attempt's process, before numpy is first imported, pins:

- ``OPENBLAS_CORETYPE``: one kernel set every CPU of the architecture runs (x86-64: ``Prescott``,
  SSE3; aarch64: ``ARMV8``), for numpy's and SciPy's OpenBLAS alike;
- ``OPENBLAS_NUM_THREADS=1``: the matrices an attempt multiplies are 3x3 to 7x7, threads gain nothing;
- ``NPY_DISABLE_CPU_FEATURES``: every numpy dispatch target above numpy's x86-64 baseline (SSE3 for
  numpy 1.x, x86-64-v2 for numpy 2.4 and later), so ufuncs take the same code path on every x86-64
  machine that numpy runs on.

The cost is nil for cab's small matrices and vectors. ``describe()`` reports what is in effect
(recorded in ``result.json`` ``versions.numerics``); ``pinned()`` says whether it is what ``pin()``
asks for (not when numpy was imported before ``cab_core``, e.g. by a host program, nor with
``CAB_NUMERICS=native``, which leaves the machine's own choices: for measuring, never for results).
"""
from __future__ import annotations

import importlib
import os
import platform
import sys

# numpy's x86 dispatch targets above its baseline, by the release that names them: numpy 2.4 groups the
# features into the x86-64 micro-architecture levels (baseline X86_V2) and ignores the older names without
# a word, while numpy before 2.4 warns on a name it does not know (an ImportWarning, an error under -W error)
_X86_DISPATCH_LEVELS = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
_X86_DISPATCH_FEATURES = ("SSSE3 SSE41 POPCNT SSE42 AVX F16C FMA3 AVX2 AVX512F AVX512CD AVX512_KNL AVX512_KNM "
                          "AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR")
_CORETYPE = {"x86_64": "Prescott", "amd64": "Prescott", "aarch64": "ARMV8", "arm64": "ARMV8"}


def _x86_dispatch() -> str:
    """The dispatch targets to disable, for the numpy this environment has installed (read from its
    metadata: numpy must not be imported before the variable is set)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        major, minor = (int(x) for x in version("numpy").split(".")[:2])
    except (PackageNotFoundError, ValueError):
        return _X86_DISPATCH_LEVELS
    return _X86_DISPATCH_LEVELS if (major, minor) >= (2, 4) else _X86_DISPATCH_FEATURES


def settings() -> dict[str, str]:
    """The environment ``pin()`` sets on this architecture."""
    arch = platform.machine().lower()
    out = {"OPENBLAS_NUM_THREADS": "1"}
    if arch in _CORETYPE:
        out["OPENBLAS_CORETYPE"] = _CORETYPE[arch]
    if arch in ("x86_64", "amd64"):
        out["NPY_DISABLE_CPU_FEATURES"] = _x86_dispatch()
    return out


def pin() -> bool:
    """Set the environment for this process (and the processes it starts); True if it took effect,
    False if numpy was already loaded (its settings are then whatever they were)."""
    if os.environ.get("CAB_NUMERICS") == "native":
        return False
    os.environ.update(settings())
    return _pinned_at_import


_pinned_at_import = "numpy" not in sys.modules


def describe() -> dict:
    """What decides this process's numerics: BLAS library, kernel set and threads, numpy's active
    dispatch targets, and whether they are the pinned ones."""
    import numpy as np

    out: dict = {"pinned": pinned()}
    try:
        from threadpoolctl import threadpool_info

        blas = [i for i in threadpool_info() if i.get("user_api") == "blas"]
        out["blas"] = [{"library": i.get("internal_api"), "version": i.get("version"),
                        "kernels": i.get("architecture"), "threads": i.get("num_threads"),
                        "file": os.path.basename(i.get("filepath") or "")} for i in blas]
    except Exception as e:  # noqa: BLE001 (provenance: say what could not be read)
        out["blas"] = f"unknown ({type(e).__name__}: {e})"
    out["numpy_dispatch"] = "unknown"
    # numpy 2 keeps its internals in numpy._core (numpy.core is a deprecated alias there)
    for module in ("numpy._core._multiarray_umath", "numpy.core._multiarray_umath"):
        try:
            umath = importlib.import_module(module)
        except ImportError:
            continue
        out["numpy_dispatch"] = [f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f)]
        break
    out["numpy"] = np.__version__
    return out


def pinned() -> bool:
    """Whether this process runs with the settings of ``pin()``: set before numpy was loaded."""
    want = settings()
    return _pinned_at_import and os.environ.get("CAB_NUMERICS") != "native" and all(os.environ.get(k) == v for k, v in want.items())
