"""A sweep's memory per slot (issue 28): warm workers forked from the sweep's fork server
(``cab_core.sweep.zygote``), and nothing of an attempt kept alive in a warm worker after it."""
from __future__ import annotations

import gc
import json
import os
import signal
import subprocess
import sys
import time
import weakref
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from cab_core.config import normalise_overrides
from cab_core.errors import ConfigError
from cab_core.sweep import worker, zygote
from cab_core.sweep.memory import children, descendants, memory_mb, pss_mb, tree_pss_mb
from cab_core.sweep.supervisor import _WORKERS, AttemptSupervisor, SupervisorConfig, close_workers


def composed(*overrides: str) -> dict:
    from omegaconf import OmegaConf

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(list(overrides)))
    out = OmegaConf.to_container(cfg, resolve=True)
    assert isinstance(out, dict)
    return out


def supervise(d: Path, settings: SupervisorConfig, cfg: dict, seen: list) -> dict:
    ident = {"task": cfg["task"]["name"], "seed": 0, "attempt": cfg["attempt"], "sim": cfg["sim"]["name"],
             "model": cfg["model"]["name"]}
    return AttemptSupervisor(cfg, d, ident, settings, on_child=lambda p, _: seen.append(p)).run()


@pytest.fixture(autouse=True)
def no_workers_left():
    close_workers()
    yield
    close_workers()


def _cmdline(pid: int) -> str:
    return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()


def test_memory_of_a_process_and_its_tree():
    proc = subprocess.Popen([sys.executable, "-c", "import time; b = bytearray(48 << 20); time.sleep(30)"])
    try:
        deadline = time.monotonic() + 20
        while pss_mb(proc.pid) < 48 and time.monotonic() < deadline:
            time.sleep(0.05)
        m = memory_mb(proc.pid)
        assert m["pss"] >= 48 and m["uss"] >= 48 and m["rss"] >= m["pss"] >= m["pss_anon"] >= 48
        assert children(os.getpid()) and proc.pid in children(os.getpid())
        assert descendants(os.getpid())[0] == os.getpid() and proc.pid in descendants(os.getpid())
        # the tree holds this process and its 48 MiB child; this process's own PSS moves by a MiB or so
        # between two reads (its threads allocate, pages it shares gain or lose sharers): 4 MiB of slack
        own = min(pss_mb(os.getpid()), pss_mb(os.getpid()))
        assert tree_pss_mb(os.getpid()) >= own + pss_mb(proc.pid) - 4.0
    finally:
        proc.kill()
        proc.wait()
    assert pss_mb(proc.pid) == 0.0 and memory_mb(proc.pid)["rss"] == 0.0  # gone


@pytest.mark.sim
def test_warm_workers_are_forked_from_one_server_and_die_with_their_supervisor(tmp_path):
    cfg = composed("sim=mujoco", "task=click_bell", "model=idle", "record.video=false")
    s = SupervisorConfig(retry_backoff_s=0.0)
    seen: list = []
    for i in range(2):
        r = supervise(tmp_path / f"a{i}", s, cfg, seen)
        assert r["termination"]["reason"] == "done"
    assert seen[0] is seen[1]  # one warm worker ran both
    [w] = _WORKERS.values()
    assert isinstance(w.proc, zygote.ForkedProcess)
    server = int(Path(f"/proc/{w.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    assert "cab_core.sweep.zygote" in _cmdline(server) and server != os.getpid()
    assert os.getsid(w.proc.pid) == w.proc.pid  # it leads its own session: kill_group reaches what it started
    # a second thread of this process gets its own worker, forked by the same server
    import threading

    other: list = []
    t = threading.Thread(target=supervise, args=(tmp_path / "b", s, cfg, other))
    t.start()
    t.join()
    w2 = other[0]
    assert w2.pid != w.proc.pid
    server2 = int(Path(f"/proc/{w2.pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    assert server2 == server
    # killed: the server reports its status as a child's wait() would
    os.kill(w.proc.pid, signal.SIGKILL)
    assert w.proc.wait(timeout=10) == -signal.SIGKILL


@pytest.mark.sim
def test_a_forked_worker_dies_when_its_supervisor_dies(tmp_path):
    code = f"""
import json, sys
from cab_core.sweep.supervisor import WarmWorker, AttemptSupervisor, SupervisorConfig
from pathlib import Path
env = AttemptSupervisor({{}}, Path({str(tmp_path)!r}), {{}}, SupervisorConfig())._env()
w = WarmWorker(env, Path({str(tmp_path / 'log')!r}), fork=True, preload=[])
print(type(w.proc).__name__, w.proc.pid, flush=True)
sys.stdin.read()
"""
    sup = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert sup.stdout is not None
    kind, pid = sup.stdout.readline().split()
    assert kind == "ForkedProcess"
    assert "cab_core.sweep.zygote" in _cmdline(int(pid))  # a fork: it carries the server's command line
    os.kill(sup.pid, signal.SIGKILL)
    sup.wait()
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and Path(f"/proc/{pid}").exists() \
            and Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z":
        time.sleep(0.05)
    gone = not Path(f"/proc/{pid}").exists() or Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    assert gone


@pytest.mark.sim
def test_without_fork_workers_each_worker_is_a_fresh_interpreter(tmp_path):
    cfg = composed("sim=mujoco", "task=click_bell", "model=idle", "record.video=false", "sweep.fork_workers=false")
    seen: list = []
    r = supervise(tmp_path / "a", SupervisorConfig.from_cfg(cfg["sweep"]), cfg, seen)
    assert r["termination"]["reason"] == "done"
    assert isinstance(seen[0], subprocess.Popen)
    assert "cab_core.sweep.worker --worker" in _cmdline(seen[0].pid)


def test_fork_workers_setting_is_checked():
    with pytest.raises(ConfigError, match="sweep.fork_workers must be true or false"):
        SupervisorConfig.from_cfg({"fork_workers": "yes"})


@pytest.mark.sim
def test_nothing_of_an_attempt_lives_on_in_a_warm_worker(tmp_path):
    """The leak a warm worker had: each attempt's world (episode, simulator with its native model and
    data, video writer) sat in reference cycles until a rare full collection, so worlds piled up."""
    from cab_core.attempt.engine.episode import Episode
    from cab_core.attempt.engine.world import BuiltWorld

    def worlds() -> list:
        return [o for o in gc.get_objects() if isinstance(o, (Episode, BuiltWorld))]

    cfg = composed("sim=mujoco", "task=click_bell", "model=oracle")  # with video: its writer is in the cycle
    enabled = gc.isenabled()
    gc.collect()
    before = {id(o) for o in worlds()}  # what other tests of this process still hold is not this attempt's
    gc.disable()  # no collection by chance: what the worker frees, it frees itself
    try:
        assert worker.run({"config": cfg, "output_dir": str(tmp_path / "a")}) == 0
        assert json.loads((tmp_path / "a" / "result.json").read_text())["verdict"]["success"] is True
        held = [weakref.ref(o) for o in worlds() if id(o) not in before]
        assert held, "the attempt left no cycle: this test no longer sees what it guards against"
        worker.release()
        assert [r() for r in held if r() is not None] == []
    finally:
        if enabled:
            gc.enable()
