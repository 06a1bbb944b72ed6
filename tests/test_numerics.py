"""The same attempt gives the same physics whatever numeric choices the machine would make: numpy's
OpenBLAS kernel set and thread count, numpy's CPU dispatch (cab_core.numerics pins them in every
attempt process). Without the pin the same attempt differs between two kernel sets on this machine,
so the comparison below can fail."""
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
MACHINES = {
    "haswell-2-threads": {"OPENBLAS_CORETYPE": "Haswell", "OPENBLAS_NUM_THREADS": "2", "NPY_DISABLE_CPU_FEATURES": ""},
    "prescott-1-thread": {"OPENBLAS_CORETYPE": "Prescott", "OPENBLAS_NUM_THREADS": "1",
                          "NPY_DISABLE_CPU_FEATURES": "AVX2 FMA3"},
}


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
        [own] = [b for b in blas[-1] if "scipy" not in b[0]]  # numpy's own OpenBLAS
        assert own[1:] == ("Prescott", 1)
    assert blas[0] == blas[1]  # every BLAS library (SciPy's too, where loaded) alike whatever the caller set


@pytest.mark.sim
@pytest.mark.skipif(not AVX2, reason="the Haswell kernel set needs AVX2")
def test_without_the_pin_the_kernel_set_changes_the_physics(tmp_path):
    """The negative control: the machine's own choices (CAB_NUMERICS=native) make a difference."""
    a, ra = attempt(tmp_path, "a", "mujoco", {**MACHINES["haswell-2-threads"], "CAB_NUMERICS": "native"})
    b, rb = attempt(tmp_path, "b", "mujoco", {**MACHINES["prescott-1-thread"], "CAB_NUMERICS": "native"})
    assert a != b
    assert ra["versions"]["numerics"]["pinned"] is False
    assert "Haswell" in [b["kernels"] for b in ra["versions"]["numerics"]["blas"]]


def test_settings_per_architecture(monkeypatch):
    monkeypatch.setattr(numerics.platform, "machine", lambda: "x86_64")
    s = numerics.settings()
    assert s["OPENBLAS_CORETYPE"] == "Prescott" and s["OPENBLAS_NUM_THREADS"] == "1"
    assert "AVX512F" in s["NPY_DISABLE_CPU_FEATURES"].split() and "SSE3" not in s["NPY_DISABLE_CPU_FEATURES"].split()
    monkeypatch.setattr(numerics.platform, "machine", lambda: "aarch64")
    assert numerics.settings() == {"OPENBLAS_NUM_THREADS": "1", "OPENBLAS_CORETYPE": "ARMV8"}


def test_this_test_process_is_pinned():
    """pytest imports cab_core (tests/conftest.py) before anything imports numpy."""
    d = numerics.describe()
    assert d["pinned"] is True, d
