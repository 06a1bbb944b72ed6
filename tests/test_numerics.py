"""The same attempt gives the same physics whatever numeric choices the machine would make: numpy's
OpenBLAS kernel set and thread count, numpy's CPU dispatch (cab_core.numerics pins them in every
attempt process). Without the pin the same numpy computations give different bits between two
kernel sets on this machine (the negative control below), so the comparison can fail.

With the mplib planner, the negative control was an attempt: unpinned, handover_block's snapshots
differed between the two kernel sets on MuJoCo. With the pin planner (numpy 2.4, pin 4.1) the same
attempt gives identical snapshots unpinned on all three simulators (measured 2026-11-28): its physics
no longer passes through a computation the kernel set changes, so the witness is numpy itself."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cab_core import numerics

CAB = os.path.join(os.path.dirname(sys.executable), "cab")
AVX2 = "avx2" in Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else False
# what differs between machines, forced here: kernel sets, BLAS threads, numpy's dispatch
NO_AVX2 = "X86_V3 X86_V4" if numerics._x86_dispatch().startswith("X86_") else "AVX2 FMA3"  # by numpy release
MACHINES = {
    "haswell-2-threads": {"OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_NUM_THREADS": "2", "NPY_DISABLE_CPU_FEATURES": ""},
    "prescott-1-thread": {"OPENBLAS_CORETYPE": "Prescott", "OPENBLAS_NUM_THREADS": "1",
                          "NPY_DISABLE_CPU_FEATURES": NO_AVX2},
}
# numpy computations whose last bits depend on the kernel set or the dispatch: a 64x64 product and
# solve (OpenBLAS) and exp over 1e5 values (numpy's SIMD loops)
WITNESS = """
import hashlib, sys
if sys.argv[1] == "pin":
    import cab_core  # pins the numerics, as in every attempt process
import numpy as np
rng = np.random.default_rng(0)
a, b, x = rng.normal(size=(64, 64)), rng.normal(size=(64, 64)), rng.uniform(-5, 5, 100000)
for v in (a @ b, np.linalg.solve(a, b), np.exp(x)):
    print(hashlib.sha256(v.tobytes()).hexdigest())
"""


def attempt(tmp: Path, name: str, sim: str, env: dict) -> tuple[list[str], dict]:
    out = tmp / name
    e = {**os.environ, **env}
    r = subprocess.run([CAB, f"sim={sim}", "task=handover_block", "model=oracle", "record.video=false",
                        f"hydra.run.dir={out}"], env=e, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    result = json.loads((out / "result.json").read_text())
    return (out / "privileged" / "snapshots.jsonl").read_text().splitlines(), result


@pytest.mark.sim
@pytest.mark.skipif(not AVX2, reason="the Haswell kernel set needs AVX2")
@pytest.mark.parametrize("sim", ["sapien", "pybullet", "mujoco"])
def test_same_snapshots_whatever_the_machines_numerics(tmp_path, sim):
    runs = {name: attempt(tmp_path, name, sim, env) for name, env in MACHINES.items()}
    (snaps_a, res_a), (snaps_b, res_b) = runs.values()
    assert len(snaps_a) > 10
    assert snaps_a == snaps_b
    assert res_a["verdict"] == res_b["verdict"] and res_a["verdict"]["success"] is True
    blas = []
    for _, res in runs.values():
        n = res["versions"]["numerics"]
        assert n["pinned"] is True and n["numpy_dispatch"] == []
        blas.append(sorted((b["file"], b["kernels"], b["threads"]) for b in n["blas"]))
        # every BLAS library (numpy's and SciPy's OpenBLAS) on one thread and the portable kernels, whatever
        # the caller set: OpenBLAS 0.3.30 and later report its Prescott choice by the older name Katmai
        assert all(b[1] in ("Prescott", "Katmai") and b[2] == 1 for b in blas[-1]), blas[-1]
    assert blas[0] == blas[1]


def _witness(mode: str, env: dict) -> list[str]:
    e = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS",
                                                          "NPY_DISABLE_CPU_FEATURES", "CAB_NUMERICS")}
    r = subprocess.run([sys.executable, "-c", WITNESS, mode], env={**e, **env}, capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.split()


@pytest.mark.skipif(not AVX2, reason="the Haswell kernel set needs AVX2")
def test_without_the_pin_the_machines_numerics_differ():
    """The negative control: the machine's own choices give other bits in each computation; the pin
    gives the same bits under both "machines"."""
    native = [_witness("native", env) for env in MACHINES.values()]
    assert len(native[0]) == 3 and all(x != y for x, y in zip(*native)), native
    pinned = [_witness("pin", env) for env in MACHINES.values()]
    assert pinned[0] == pinned[1]
    assert pinned[0] == native[1]  # the pin chooses the portable kernels that the older machine takes
    assert _witness("pin", {"CAB_NUMERICS": "native", **MACHINES["haswell-2-threads"]}) == native[0]


def numpy_version() -> tuple[int, int]:
    from importlib.metadata import version

    major, minor = version("numpy").split(".")[:2]
    return int(major), int(minor)


@pytest.mark.parametrize("installed, disabled", [("2.4.6", "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"),
                                                  ("2.5.0", "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"),
                                                  ("2.3.5", "AVX2"), ("1.26.4", "AVX2")])
def test_dispatch_names_follow_the_installed_numpy(monkeypatch, installed, disabled):
    import importlib.metadata

    monkeypatch.setattr(importlib.metadata, "version", lambda name: installed)
    monkeypatch.setattr(numerics.platform, "machine", lambda: "x86_64")
    names = numerics.settings()["NPY_DISABLE_CPU_FEATURES"].split()
    assert set(disabled.split()) <= set(names)
    assert ("X86_V3" in names) == installed.startswith(("2.4", "2.5"))


def test_settings_per_architecture(monkeypatch):
    monkeypatch.setattr(numerics.platform, "machine", lambda: "x86_64")
    s = numerics.settings()
    assert s["OPENBLAS_CORETYPE"] == "Prescott" and s["OPENBLAS_NUM_THREADS"] == "1"
    disabled = s["NPY_DISABLE_CPU_FEATURES"].split()
    assert "SSE3" not in disabled and "X86_V2" not in disabled  # numpy's baselines stay
    assert "AVX512_SPR" in disabled and ("X86_V3" in disabled) == (numpy_version() >= (2, 4))
    monkeypatch.setattr(numerics.platform, "machine", lambda: "aarch64")
    assert numerics.settings() == {"OPENBLAS_NUM_THREADS": "1", "OPENBLAS_CORETYPE": "ARMV8"}


def test_this_test_process_is_pinned():
    """pytest imports cab_core (tests/conftest.py) before anything imports numpy."""
    d = numerics.describe()
    assert d["pinned"] is True, d
