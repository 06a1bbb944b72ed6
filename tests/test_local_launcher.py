"""cab's default sweep launcher (hydra_plugins/cab_launcher): jobs in threads of the ``cab -m``
process, Hydra's process-wide state kept per thread, each job's log its own, no launcher process
per slot, and Ctrl-C or SIGTERM ending a sweep at once with one line and no scored attempt."""
from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton

from cab_core.sweep.memory import descendants
from cab_core.testing.fake_openai import FakeOpenAIServer
from hydra_plugins.cab_launcher.local_launcher import LocalLauncher, _JobFiles, _per_thread

CAB = os.path.join(os.path.dirname(sys.executable), "cab")


def test_hydra_config_is_per_thread_while_jobs_run():
    before = HydraConfig.instance()
    before_cfg = before.cfg
    seen: dict[str, object] = {}
    with _per_thread():
        shared = HydraConfig.instance()
        assert shared is not before and shared.cfg is before_cfg  # a thread that set none sees the launch's

        def job(name: str, barrier: threading.Barrier) -> None:
            HydraConfig.instance().cfg = name  # what run_job's set_config does
            barrier.wait()  # both threads have set theirs before either reads
            seen[name] = HydraConfig.instance().cfg

        barrier = threading.Barrier(2)
        threads = [threading.Thread(target=job, args=(n, barrier)) for n in ("a", "b")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert HydraConfig.instance().cfg is before_cfg  # the launching thread's is untouched
    assert seen == {"a": "a", "b": "b"}
    assert Singleton._instances[HydraConfig] is before and HydraConfig.instance().cfg is before_cfg


def test_each_job_log_gets_only_its_own_threads_records(tmp_path):
    router = _JobFiles()
    root = logging.getLogger()
    root.addHandler(router)
    old_level = root.level
    root.setLevel(logging.INFO)
    log = logging.getLogger("cab.test_local_launcher")
    try:
        def job(name: str, barrier: threading.Barrier) -> None:
            h = logging.FileHandler(tmp_path / f"{name}.log")
            h.setFormatter(logging.Formatter("%(message)s"))
            router.open([h])
            barrier.wait()
            for i in range(3):
                log.info(f"{name} {i}")
            barrier.wait()
            router.close_job()

        barrier = threading.Barrier(2)
        threads = [threading.Thread(target=job, args=(n, barrier)) for n in ("a", "b")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        log.info("not a job's")
    finally:
        root.removeHandler(router)
        root.setLevel(old_level)
    for name in ("a", "b"):
        assert (tmp_path / f"{name}.log").read_text().splitlines() == [f"{name} {i}" for i in range(3)]


@pytest.mark.parametrize("n_jobs, jobs, cores, slots", [(4, 10, 2, 4), (4, 3, 2, 3), (-1, 10, 2, 2),
                                                        (-2, 10, 8, 7), (-5, 10, 2, 1)])
def test_slots_count_as_joblib_does(monkeypatch, n_jobs, jobs, cores, slots):
    monkeypatch.setattr(os, "cpu_count", lambda: cores)
    assert LocalLauncher(n_jobs=n_jobs).slots(jobs) == slots


def _cmd(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
    except OSError:
        return ""


def _running(pid: int) -> bool:
    """Alive, not a zombie waiting to be reaped."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def _tree(pid: int) -> dict[str, list[int]]:
    """The sweep's processes by role: main, fork server (a child of main), attempt workers (its children)."""
    out: dict[str, list[int]] = {}
    for p in descendants(pid):
        cmd = _cmd(p)
        role = ("main" if p == pid else "fork server" if "cab_core.sweep.zygote" in cmd and p in _children(pid)
                else "attempt worker" if "cab_core.sweep.zygote" in cmd or "cab_core.sweep.worker" in cmd
                else cmd.split(" ")[0].rsplit("/", 1)[-1])
        out.setdefault(role, []).append(p)
    return out


def _children(pid: int) -> list[int]:
    from cab_core.sweep.memory import children

    return children(pid)


@pytest.mark.sim
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_model_sweep_runs_in_threads_and_stops_at_once(tmp_path, sig):
    """Two attempts waiting on their model: the sweep's processes are itself, the fork server and
    the two attempt workers (no launcher process per slot); the signal ends it within seconds, in
    one line, exit 130, no result.json written and no attempt process left."""
    sweep = tmp_path / "sweep"
    with FakeOpenAIServer(latency_s=3600) as fake:
        cmd = [CAB, "-m", "task=click_bell", "sim=mujoco", "model=qwen_local", f"model.base_url={fake.base_url}",
               "model.model_id=cab-fake", "attempt=1,2,3", "hydra.launcher.n_jobs=2", f"hydra.sweep.dir={sweep}",
               "record.video=false", "sweep.preflight_network=false", "model.probe=false"]
        proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                start_new_session=True)
        try:
            deadline = time.monotonic() + 300
            while fake.requests < 2:
                assert proc.poll() is None, proc.communicate()[1][-3000:]
                assert time.monotonic() < deadline, "two attempts did not ask their model within 300 s"
                time.sleep(0.2)
            tree = _tree(proc.pid)
            t0 = time.monotonic()
            os.kill(proc.pid, sig)
            _, err = proc.communicate(timeout=60)
            stopped_s = time.monotonic() - t0
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    assert sorted(tree) == ["attempt worker", "fork server", "main"], tree  # no launcher process per slot
    assert len(tree["attempt worker"]) == 2 and len(tree["fork server"]) == 1, tree
    assert proc.returncode == 130, err[-3000:]
    assert err.strip().splitlines() == [
        f"cab: sweep {sweep} interrupted; finished attempts are kept, those in flight are not scored: run the same "
        f"command to resume: cab {' '.join(cmd[1:])}"], err[-3000:]
    assert stopped_s < 10
    assert not list(sweep.rglob("result.json"))
    deadline = time.monotonic() + 10
    while any(_running(p) for p in tree["attempt worker"]) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [p for p in tree["attempt worker"] if _running(p)]  # they die with the sweep's process


def test_chdir_is_refused_in_one_line_before_anything_runs(tmp_path):
    """Jobs in threads share one working directory: hydra.job.chdir=true cannot be honoured."""
    sweep = tmp_path / "sweep"
    r = subprocess.run([CAB, "-m", "task=click_bell", "sim=mujoco", "attempt=1,2", "hydra.job.chdir=true",
                        f"hydra.sweep.dir={sweep}"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        "cab: hydra.job.chdir=true cannot work with cab's launcher (its jobs are threads of one process, which has "
        "one working directory): leave it false, or use hydra/launcher=joblib"]
    assert not sweep.exists()
