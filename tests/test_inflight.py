"""Attempts in flight independent of cores (issue 28, item 6): the default concurrency from memory
for model-bound sweeps, the machine-wide CPU slot pool, the order of the paper's jobs, and the
benchmark's fake OpenAI-compatible model answering the real ``openai`` client."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module
from omegaconf import OmegaConf

from cab_core.attempt.engine.cpu_slots import CpuSlots
from cab_core.conf.in_flight import DEFAULT_SLOT_MEMORY_MB, in_flight
from cab_core.config import _swept_options

ROOT = Path(__file__).resolve().parents[1]


# -- the default concurrency ----------------------------------------------------------------------

def test_model_bound_sweeps_fill_memory_not_cores():
    got = in_flight(None, True, 280, cap=128, reserve_mb=2048, available_mb=22000, n_cores=2)
    assert got.n == (22000 - 2048) // 280 == 71
    assert "280 MiB per slot" in got.why


def test_the_cap_bounds_it_and_at_least_one_runs():
    assert in_flight(None, True, 100, cap=64, reserve_mb=0, available_mb=100000, n_cores=2).n == 64
    assert in_flight(None, True, 400, cap=64, reserve_mb=2048, available_mb=1000, n_cores=2).n == 1


def test_model_free_sweeps_keep_one_per_core_and_a_setting_is_used_as_is():
    assert in_flight(None, False, 280, cap=128, reserve_mb=2048, available_mb=22000, n_cores=6).n == 6
    assert in_flight(7, True, 280, cap=128, reserve_mb=2048, available_mb=22000, n_cores=2).n == 7


def _launcher_jobs(*overrides: str) -> int:
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=list(overrides), return_hydra_config=True)
    return int(cfg.hydra.launcher.n_jobs)


def test_the_launcher_takes_its_n_jobs_from_the_resolver(monkeypatch):
    monkeypatch.setattr("cab_core.conf.in_flight.available_memory_mb", lambda: 2048 + 10 * 160 + 100)
    monkeypatch.setattr("cab_core.conf.in_flight.cores", lambda: 3)
    assert _launcher_jobs("model=qwen_local", "sim=mujoco") == 10  # mujoco.yaml: slot_memory_mb 160
    assert _launcher_jobs("model=idle", "sim=mujoco") == 3  # model-free: one per core
    assert _launcher_jobs("model=qwen_local", "sim=mujoco", "sweep.max_in_flight=5") == 5
    assert _launcher_jobs("model=qwen_local", "sim=mujoco", "sweep.memory_reserve_mb=0",
                          "sweep.in_flight_cap=4") == 4
    # the paper sweeps nine model configurations (hydra.sweeper.params) on the default simulator
    monkeypatch.setattr("cab_core.conf.in_flight.available_memory_mb", lambda: 2048 + 10 * 210 + 100)
    assert _launcher_jobs("experiment=paper", "sim=sapien") == 10  # sapien.yaml: 210


def test_swept_options_are_read_from_the_overrides_and_the_sweepers_params():
    root = OmegaConf.create({"hydra": {"overrides": {"task": ["model=idle,oracle", "sim=mujoco"]},
                                       "sweeper": {"params": {"task": "a,b"}}}})
    assert _swept_options(root, "model") == ["idle", "oracle"]
    assert _swept_options(root, "sim") is None  # one value: the composed config's
    root = OmegaConf.create({"hydra": {"overrides": {"task": []}, "sweeper": {"params": {"sim": "mujoco,sapien"}}}})
    assert _swept_options(root, "sim") == ["mujoco", "sapien"]


def test_a_sweep_of_model_free_agents_keeps_one_per_core_and_one_with_a_model_fills_memory(monkeypatch):
    from cab_core.config import in_flight as resolver
    monkeypatch.setattr("cab_core.conf.in_flight.available_memory_mb", lambda: 2048 + 6 * 280)
    monkeypatch.setattr("cab_core.conf.in_flight.cores", lambda: 2)

    def root(models: str, sims: str = "mujoco") -> object:
        return OmegaConf.create({"sweep": {"in_flight_cap": 128, "memory_reserve_mb": 2048},
                                 "model": {"name": "x", "agent": None}, "sim": {"name": "mujoco", "slot_memory_mb": 200},
                                 "hydra": {"overrides": {"task": [f"model={models}", f"sim={sims}"]}}})
    assert resolver(None, _root_=root("idle,oracle")) == 2
    assert resolver(None, _root_=root("idle,qwen_local")) == 6 * 280 // 200
    # the largest slot of the simulators swept; one without a figure counts DEFAULT_SLOT_MEMORY_MB
    assert resolver(None, _root_=root("qwen_local", "mujoco,sapien")) == 6 * 280 // 210  # sapien.yaml: slot_memory_mb 210
    assert resolver(None, _root_=root("qwen_local", "mujoco,pybullet")) == 6 * 280 // DEFAULT_SLOT_MEMORY_MB


def test_a_bad_max_in_flight_is_one_line_exit_2(tmp_path):
    r = subprocess.run([os.path.join(os.path.dirname(sys.executable), "cab"), "task=click_bell", "sim=mujoco",
                        "model=idle", "sweep.max_in_flight=0"], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2
    assert "sweep.max_in_flight must be a positive integer, or null" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


# -- the order of the paper's jobs ---------------------------------------------------------------

def test_the_paper_varies_the_model_fastest():
    """Hydra's basic sweeper varies the last key fastest: the nine configurations alternate."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = OmegaConf.load(ROOT / "conf/experiment/paper.yaml").hydra.sweeper.params
    assert list(params)[-1] == "model"
    parsed = OverridesParser.create().parse_overrides([f"{k}={v}" for k, v in params.items()])
    jobs = BasicSweeper.split_arguments(parsed, None)[0]
    models = [dict(o.split("=", 1) for o in job)["model"] for job in jobs]
    assert len(jobs) == 675
    assert models[:9] == str(params.model).split(",")
    assert all(len(set(models[i:i + 9])) == 9 for i in range(0, 675, 9))


# -- the CPU slot pool ---------------------------------------------------------------------------

HOLDER = textwrap.dedent("""
    import sys, time
    from cab_core.attempt.engine.cpu_slots import CpuSlots
    pool = CpuSlots(int(sys.argv[2]), sys.argv[1])
    pool.acquire()
    print("held", flush=True)
    time.sleep(float(sys.argv[3]))
""")

WAITER = textwrap.dedent("""
    import json, resource, sys, time
    from cab_core.attempt.engine.cpu_slots import CpuSlots
    pool = CpuSlots(int(sys.argv[2]), sys.argv[1])
    print("waiting", flush=True)
    t0 = time.monotonic()
    c0 = time.process_time()
    waited = pool.acquire()
    print(json.dumps({"waited": waited, "wall": time.monotonic() - t0, "cpu": time.process_time() - c0}), flush=True)
""")


def _holder(folder: Path, n: int, hold_s: float) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder), str(n), str(hold_s)], stdout=subprocess.PIPE,
                         text=True)
    assert p.stdout is not None and p.stdout.readline().strip() == "held"
    return p


def test_a_waiter_blocks_until_a_slot_is_released_without_spinning(tmp_path):
    holders = [_holder(tmp_path, 2, 60), _holder(tmp_path, 2, 60)]
    try:
        waiter = subprocess.Popen([sys.executable, "-c", WAITER, str(tmp_path), "2"], stdout=subprocess.PIPE, text=True)
        assert waiter.stdout is not None and waiter.stdout.readline().strip() == "waiting"
        time.sleep(1.5)
        assert waiter.poll() is None  # both slots are held: it waits
        holders[0].kill()  # a slot is free: it goes on
        got = json.loads(waiter.communicate(timeout=30)[0])
        assert got["waited"] >= 1.4
        assert got["cpu"] < 0.05 * got["waited"]  # blocked in the kernel: no polling
    finally:
        for h in holders:
            h.kill()
            h.wait()


def test_a_slot_of_a_killed_holder_is_free_at_once(tmp_path):
    h = _holder(tmp_path, 1, 60)
    h.kill()
    h.wait()
    pool = CpuSlots(1, tmp_path)
    t0 = time.monotonic()
    with pool.held():
        assert time.monotonic() - t0 < 1.0


def test_holding_is_reentrant_and_released_by_the_outermost(tmp_path):
    pool = CpuSlots(1, tmp_path)
    with pool.held():
        with pool.held():  # a call served inside the set-up's hold
            pass
        assert CpuSlots(1, tmp_path)._try_any() is None  # still held after the inner hold ended
    other = CpuSlots(1, tmp_path)
    assert other._try_any() is not None  # free once the outermost hold ended
    with pytest.raises(RuntimeError):
        pool.release()


def test_n_slots_let_n_hold_at_once(tmp_path):
    pools = [CpuSlots(3, tmp_path) for _ in range(3)]
    fds = [p._try_any() for p in pools]
    assert all(fd is not None for fd in fds)
    assert CpuSlots(3, tmp_path)._try_any() is None
    for fd in fds:
        assert fd is not None
        os.close(fd)


def test_world_builds_are_staggered_by_the_pool(tmp_path):
    """Start-ups at once take turns: with one slot, three holds of 0.4 s end about 0.4 s apart."""
    script = textwrap.dedent("""
        import sys, time
        from cab_core.attempt.engine import cpu_slots
        with cpu_slots.held():
            time.sleep(0.4)
            print(time.monotonic(), flush=True)
    """)
    env = {**os.environ, "CAB_CPU_SLOTS": "1", "CAB_CPU_SLOTS_DIR": str(tmp_path)}
    procs = [subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env=env)
             for _ in range(3)]
    ends = sorted(float(p.communicate(timeout=30)[0]) for p in procs)
    assert all(b - a >= 0.35 for a, b in zip(ends, ends[1:])), ends


def test_no_pool_without_its_environment(monkeypatch):
    from cab_core.attempt.engine import cpu_slots
    monkeypatch.delenv(cpu_slots.ENV, raising=False)
    assert cpu_slots.pool() is None
    with cpu_slots.held():
        pass


def test_the_supervisor_turns_the_pool_on_for_its_attempts(tmp_path):
    from cab_core.attempt.engine import cpu_slots
    from cab_core.sweep.supervisor import AttemptSupervisor, SupervisorConfig

    on = AttemptSupervisor({}, tmp_path, {}, SupervisorConfig.from_cfg({}), tmp_path / "log")._env()
    off = AttemptSupervisor({}, tmp_path, {}, SupervisorConfig.from_cfg({"cpu_slots": False}), tmp_path / "log")._env()
    assert on[cpu_slots.ENV] == str(os.cpu_count()) and off[cpu_slots.ENV] == "0"


# -- the benchmark's fake model ------------------------------------------------------------------

def test_the_fake_model_answers_the_openai_client_after_its_latency():
    openai = pytest.importorskip("openai")
    from cab_core.testing.fake_openai import CLICK_BELL_SCRIPT, MODEL_ID, FakeOpenAIServer

    tools = [{"type": "function", "function": {"name": n, "parameters": {"type": "object"}}}
             for n in {name for name, _ in CLICK_BELL_SCRIPT}]
    with FakeOpenAIServer(0.2) as server:
        client = openai.OpenAI(base_url=server.base_url, api_key="none", max_retries=0)
        assert [m.id for m in client.models.list()] == [MODEL_ID]
        messages: list[dict] = [{"role": "user", "content": "press the bell"}]
        names = []
        t0 = time.monotonic()
        for turn in range(len(CLICK_BELL_SCRIPT)):
            r = client.chat.completions.create(model=MODEL_ID, messages=messages, tools=tools)  # type: ignore[arg-type]
            call = r.choices[0].message.tool_calls[0]  # type: ignore[index]
            assert r.choices[0].finish_reason == "tool_calls" and call.id == f"call_{turn}"
            names.append(call.function.name)  # type: ignore[union-attr]
            assert json.loads(call.function.arguments) == CLICK_BELL_SCRIPT[turn][1]  # type: ignore[union-attr]
            messages += [{"role": "assistant", "content": None, "tool_calls": [call.model_dump()]},
                         {"role": "tool", "tool_call_id": call.id, "content": "{}"}]
        assert time.monotonic() - t0 >= 0.2 * len(CLICK_BELL_SCRIPT)
        assert names == [n for n, _ in CLICK_BELL_SCRIPT] and names[-1] == "done" and len(names) == 16
        # no tools: a plain answer, a code word it was asked to remember given back
        r = client.chat.completions.create(model=MODEL_ID, messages=[
            {"role": "user", "content": "Remember this code word: PELICAN-7731.\n\nblah. What was it?"}])
        assert r.choices[0].message.content == "PELICAN-7731" and r.choices[0].finish_reason == "stop"
        assert server.requests == 17


def test_the_benchmark_runs_attempts_in_flight_against_the_fake_model(tmp_path):
    """The tiny run: 2 attempts, both in flight, 0.2 s turns, MuJoCo, click_bell (one sweep)."""
    out = tmp_path / "bench"
    r = subprocess.run([os.path.join(os.path.dirname(sys.executable), "cab-bench-sweep"), "--out", str(out),
                        "--task", "click_bell", "--sim", "mujoco", "--fake-model-latency", "0.2", "--workers", "2",
                        "--attempts", "2", "--json", str(tmp_path / "b.json")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads((tmp_path / "b.json").read_text())
    assert [(row["workers"], row["attempts"]) for row in got["rows"]] == [(2, 2)]
    for row in got["rows"]:
        assert row["cpu_s_per_attempt"] > 0 and row["pss_mb_per_slot"] > 0
    for res in out.glob("**/result.json"):
        result = json.loads(res.read_text())
        assert result["termination"]["reason"] == "done" and result["budget"]["tool_calls_used"] == 15
    assert len(list(out.glob("**/result.json"))) == 2
    projection = {p["n"]: p for p in got["paper_projection"]}
    assert {1, 8, 32, 64} <= set(projection) and sum(p["default"] for p in projection.values()) == 1
    assert projection[1]["hours_paper_mean"] == pytest.approx(675 * 23.3 / 60, rel=0.01)  # length, not CPU, binds
    assert projection[64]["hours_astra_median"] < projection[8]["hours_astra_median"]
    assert ("| 64 |" in r.stdout or "| 64 (default here) |" in r.stdout) and "23.3 min" in r.stdout


def test_a_program_and_its_robot_calls_run_under_a_one_slot_pool(tmp_path):
    """run_code holds no slot for the whole program, each robot call it makes holds one: under a pool of
    one slot an attempt whose program calls the robot finishes (no waiting on itself)."""
    from cab_core.testing.fake_openai import MODEL_ID, FakeOpenAIServer

    script = (("run_code", {"code": "state = get_robot_state()\nresult = sorted(state)"}),
              ("done", {"report": "read the state in a program", "success_claim": False}))
    env = {**os.environ, "CAB_CPU_SLOTS": "1", "CAB_CPU_SLOTS_DIR": str(tmp_path / "slots")}
    with FakeOpenAIServer(0.0, script) as server:
        r = subprocess.run([os.path.join(os.path.dirname(sys.executable), "cab"), "task=click_bell", "sim=mujoco",
                            "model=qwen_local", f"model.base_url={server.base_url}", f"model.model_id={MODEL_ID}",
                            "model.probe=false", "record.video=false", f"hydra.run.dir={tmp_path / 'run'}"],
                           capture_output=True, text=True, env=env, timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    calls = [json.loads(line) for line in (tmp_path / "run" / "events.jsonl").read_text().splitlines()]
    internal = [e for e in calls if e.get("kind") == "internal_call"]
    assert [e["tool"] for e in internal] == ["get_robot_state"]
    assert json.loads((tmp_path / "run" / "result.json").read_text())["termination"]["reason"] == "done"
