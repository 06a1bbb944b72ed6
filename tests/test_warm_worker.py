"""Warm workers (``sweep.warm_workers``): attempts run one after another in one process that keeps
its renderer, and nothing leaks from one attempt into the next: the same attempt gives the same
states and the same images after other attempts in a worker as in a fresh process. A worker that
dies is replaced, one over its memory limit is killed and its attempt retried, and a worker is
retired after its quota of attempts."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from cab_core.apps.cli import normalise_overrides
from cab_core.errors import ConfigError
from cab_core.sweep.attempt_state import infrastructure_failures, is_infrastructure_failure
from cab_core.sweep.supervisor import _WORKERS, AttemptSupervisor, SupervisorConfig, close_workers


def composed(*overrides: str) -> dict:
    from omegaconf import OmegaConf

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(list(overrides)))
    return OmegaConf.to_container(cfg, resolve=True)


def identity(cfg: dict) -> dict:
    return {"task": cfg["task"]["name"], "seed": 0, "attempt": cfg["attempt"], "sim": cfg["sim"]["name"],
            "model": cfg["model"]["name"]}


class Pids:
    def __init__(self):
        self.seen: list[int] = []

    def __call__(self, proc, try_no: int) -> None:
        self.seen.append(proc.pid)


def supervise(d: Path, settings: SupervisorConfig, *overrides: str, pids: Pids | None = None) -> dict:
    cfg = composed(*overrides)
    return AttemptSupervisor(cfg, d, identity(cfg), settings, on_child=pids).run()


@pytest.fixture(autouse=True)
def no_workers_left():
    close_workers()
    yield
    close_workers()


def evidence(d: Path) -> dict:
    """What the same attempt must reproduce: every state snapshot, every observation's pixels, the
    outcome and the budget used."""
    import json

    r = json.loads((d / "result.json").read_text())
    return {"snapshots": (d / "privileged" / "snapshots.jsonl").read_text().splitlines(),
            "observations": {p.name: p.read_bytes() for p in sorted((d / "observations").glob("*.png"))},
            "verdict": r["verdict"], "termination": r["termination"]["reason"],
            "budget": {k: v for k, v in r["budget"].items() if "wall" not in k}}


@pytest.mark.sim
@pytest.mark.slow
def test_same_attempt_same_states_and_images_after_other_attempts_in_one_worker(tmp_path):
    a = ("task=click_bell", "model=oracle", "record.video=false")
    b = ("task=press_stapler", "model=oracle", "record.video=false")
    fresh = supervise(tmp_path / "fresh", SupervisorConfig(warm_workers=False), *a)
    pids = Pids()
    warm = SupervisorConfig(warm_workers=True)
    supervise(tmp_path / "w1", warm, *a, pids=pids)
    supervise(tmp_path / "w2", warm, *b, pids=pids)
    again = supervise(tmp_path / "w3", warm, *a, pids=pids)
    assert len(set(pids.seen)) == 1 and len(pids.seen) == 3  # one process ran all three
    assert fresh["verdict"]["success"] is True and again["verdict"]["success"] is True
    e = evidence(tmp_path / "fresh")
    assert len(e["snapshots"]) > 3 and len(e["observations"]) >= 1
    assert evidence(tmp_path / "w1") == e
    assert evidence(tmp_path / "w3") == e
    assert infrastructure_failures(tmp_path / "w3") == []
    # each attempt's output went to its own log, none to another's
    logs = [(tmp_path / n / "attempt.log").read_text() for n in ("w1", "w2", "w3")]
    assert all("press_stapler" not in log for i, log in enumerate(logs) if i != 1)


@pytest.mark.sim
def test_dead_worker_is_replaced_and_quota_retires_a_worker(tmp_path):
    idle = ("sim=mujoco", "task=click_bell", "model=idle", "record.video=false")
    pids = Pids()
    s = SupervisorConfig(retry_backoff_s=0.0, worker_max_attempts=2)
    for i in range(3):
        r = supervise(tmp_path / f"a{i}", s, *idle, pids=pids)
        assert r["termination"]["reason"] == "done" and not is_infrastructure_failure(r)
    assert pids.seen[0] == pids.seen[1] != pids.seen[2]  # the quota of two attempts retired the first
    [worker] = _WORKERS.values()
    os.kill(worker.proc.pid, signal.SIGKILL)  # dies between attempts: not the next attempt's failure
    worker.proc.wait()
    r = supervise(tmp_path / "a3", s, *idle, pids=pids)
    assert pids.seen[3] != pids.seen[2]
    assert r["termination"]["reason"] == "done" and infrastructure_failures(tmp_path / "a3") == []


@pytest.mark.sim
def test_worker_over_its_memory_limit_is_killed_and_the_attempt_retried(tmp_path):
    s = SupervisorConfig(max_retries=1, retry_backoff_s=0.0, worker_max_rss_mb=60, poll_s=0.1)
    r = supervise(tmp_path / "a", s, "sim=mujoco", "task=click_bell", "model=idle", "record.video=false")
    assert is_infrastructure_failure(r)
    fails = infrastructure_failures(tmp_path / "a")
    assert [f["kind"] for f in fails] == ["memory", "memory"]
    assert "more than 60 MiB" in fails[0]["detail"]
    assert _WORKERS == {}


@pytest.mark.parametrize("cfg, word", [({"warm_workers": "yes"}, "warm_workers"),
                                       ({"worker_max_attempts": 0}, "worker_max_attempts"),
                                       ({"worker_max_attempts": True}, "worker_max_attempts"),
                                       ({"worker_max_rss_mb": -1}, "worker_max_rss_mb")])
def test_worker_settings_are_checked(cfg, word):
    with pytest.raises(ConfigError, match=word):
        SupervisorConfig.from_cfg(cfg)
