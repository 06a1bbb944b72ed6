"""Sweeps as a user runs them: ``cab -m`` killed with SIGKILL midway and resumed, a changed
configuration refused, the Ray launcher on a local Ray instance, and the supervisor's handling of
infrastructure failures (a crashed and a hung simulator process, a provider outage)."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_module

from cab_core.apps.cli import normalise_overrides
from cab_core.sweep.attempt_state import check_attempt, infrastructure_failures, is_infrastructure_failure
from cab_core.sweep.manifest import MANIFEST, config_diff, fingerprint
from cab_core.sweep.supervisor import AttemptSupervisor, SupervisorConfig

CAB = os.path.join(os.path.dirname(sys.executable), "cab")
ATTEMPTS = (1, 2, 3, 4)


# The attempts of these sweeps must stay in flight long enough to be caught there: an idle attempt
# ends in a few tenths of a second, so each runs one program that computes for a couple of seconds
# (longer on a loaded machine, which only widens the window) and then gives up.
BUSY_SCRIPT = [{"tool": "run_code", "args": {"code": "s = 0\nfor i in range(40_000_000):\n    s += i\nprint(s)"}},
               {"tool": "done", "args": {"report": "computed, then gave up", "success_claim": False}}]


def busy_script(where: Path) -> Path:
    p = where / "busy.jsonl"
    p.write_text("".join(json.dumps(item) + "\n" for item in BUSY_SCRIPT))
    return p


def sweep_cmd(sweep_dir: Path, *extra: str, attempts=ATTEMPTS, workers: int = 2) -> list[str]:
    """The sweep of these tests; its scripted agent's file lies beside the sweep directory."""
    return [CAB, "-m", "task=beat_block_hammer", "model=scripted", f"model.script={busy_script(sweep_dir.parent)}",
            f"attempt={','.join(map(str, attempts))}", "record.video=false", f"hydra.sweep.dir={sweep_dir}",
            f"hydra.launcher.n_jobs={workers}", *extra]


def attempt_dirs(sweep_dir: Path) -> dict[int, Path]:
    return {a: sweep_dir / "beat_block_hammer" / "scripted" / "sapien" / "seed-0" / f"attempt-{a}" for a in ATTEMPTS}


def fingerprints(d: Path) -> dict:
    """What must not change when an attempt is skipped: identity and content of its records."""
    out = {}
    for name in ("result.json", "events.jsonl", "privileged/snapshots.jsonl"):
        st = os.stat(d / name)
        out[name] = (st.st_ino, st.st_mtime_ns, (d / name).read_bytes())
    return out


def end_group(proc: subprocess.Popen) -> None:
    """If ``proc`` (started with ``start_new_session=True``, so it leads a process group of its own) is
    still running, SIGKILL its whole group and reap it."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


@pytest.fixture(scope="module")
def killed_and_resumed(tmp_path_factory):
    """Run a 4-attempt sweep on 2 workers, SIGKILL the whole process group as soon as one attempt
    has finished while another is half-written, then run the same command again. The half-written
    attempt can still finish between the look and the kill; then the sweep is started afresh in a
    new directory (at most three times), so the test always resumes the state it means to."""
    for _ in range(3):
        root = tmp_path_factory.mktemp("sweep")
        sweep = root / "sw"
        dirs = attempt_dirs(sweep)
        proc = subprocess.Popen(sweep_cmd(sweep), cwd=root, start_new_session=True, stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 600
        try:
            while time.monotonic() < deadline:
                done = {a for a, d in dirs.items() if (d / "result.json").exists()}
                half = {a for a, d in dirs.items() if (d / "events.jsonl").exists() and a not in done}
                if done and half:
                    break
                assert proc.poll() is None, f"the sweep ended before it could be killed: {proc.stderr.read()}"
                time.sleep(0.1)
            else:
                pytest.fail("no moment with one finished and one half-written attempt within 600 s")
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        time.sleep(1.0)  # let the kernel reap the attempt processes (they die with their worker)
        done = {a for a, d in dirs.items() if (d / "result.json").exists()}
        half = {a for a, d in dirs.items() if (d / "events.jsonl").exists() and a not in done}
        if done and half:
            break
    before = {a: fingerprints(dirs[a]) for a in done}
    half_events = {a: (dirs[a] / "events.jsonl").read_bytes() for a in half}
    r = subprocess.run(sweep_cmd(sweep), cwd=root, capture_output=True, text=True, timeout=900)
    return {"root": root, "sweep": sweep, "dirs": dirs, "done": done, "half": half, "before": before,
            "half_events": half_events, "rerun": r}


@pytest.mark.sim
@pytest.mark.slow
def test_resumed_sweep_redoes_no_finished_attempt(killed_and_resumed):
    k = killed_and_resumed
    assert k["rerun"].returncode == 0, k["rerun"].stderr[-3000:]
    assert k["done"] and k["half"]
    for a, fp in k["before"].items():
        assert fingerprints(k["dirs"][a]) == fp, f"attempt {a} was redone"
        assert not (k["dirs"][a] / "set_aside").exists()
    for a, d in k["dirs"].items():
        check = check_attempt(d, {"task": "beat_block_hammer", "attempt": a, "model": "scripted"}, "cli.log")
        assert check.state == "complete", (a, check.problems)
        if a not in k["done"]:  # (the kill may fall between a result and the supervisor's note on it)
            assert check.result["infrastructure"] == {"failed": False, "failures": []}
    skipped = [line for line in k["rerun"].stderr.splitlines() if "complete already, skipped" in line]
    assert len(skipped) == len(k["done"])
    assert sum("cab sweep [" in line for line in k["rerun"].stderr.splitlines()) == len(ATTEMPTS)
    assert k["rerun"].stderr.splitlines()[-1] == f"cab sweep: 4/4 attempts complete; {k['sweep']}"


@pytest.mark.sim
@pytest.mark.slow
def test_half_written_attempt_is_set_aside_and_rerun(killed_and_resumed):
    k = killed_and_resumed
    for a in k["half"]:
        aside = k["dirs"][a] / "set_aside" / "01-interrupted"
        assert (aside / "events.jsonl").read_bytes() == k["half_events"][a]
        assert not (aside / "result.json").exists()
        assert (k["dirs"][a] / "result.json").exists()


@pytest.mark.sim
@pytest.mark.slow
def test_manifest_pins_the_configuration(killed_and_resumed):
    k = killed_and_resumed
    m = json.loads((k["sweep"] / MANIFEST).read_text())
    assert m["n_jobs"] == 4 and len(m["sessions"]) == 2
    assert m["jobs"] == [[f"attempt={a}"] for a in ATTEMPTS]
    assert m["config"]["record"]["video"] is False and "hydra" not in m["config"] and "sweep" not in m["config"]
    assert m["fingerprint"] == fingerprint(m["config"], m["jobs"])
    assert m["sessions"][1]["complete_at_start"] == len(k["done"])
    r = subprocess.run(sweep_cmd(k["sweep"], "budget.tool_calls=5"), cwd=k["root"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert "refused" in r.stderr and "budget.tool_calls: None -> 5" in r.stderr
    r = subprocess.run(sweep_cmd(k["sweep"], attempts=(*ATTEMPTS, 5)), cwd=k["root"], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "1 job(s) added, e.g. [attempt=5]" in r.stderr
    assert json.loads((k["sweep"] / MANIFEST).read_text())["sessions"] == m["sessions"]  # refusals change nothing
    # the worker count and the infrastructure settings are not part of the fingerprint
    r = subprocess.run(sweep_cmd(k["sweep"], "sweep.hang_timeout_s=1200", workers=1), cwd=k["root"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    assert sum("complete already, skipped" in line for line in r.stderr.splitlines()) == len(ATTEMPTS)
    assert len(json.loads((k["sweep"] / MANIFEST).read_text())["sessions"]) == 3


@pytest.mark.sim
@pytest.mark.slow
def test_record_checks_catch_incomplete_records(killed_and_resumed, tmp_path):
    src = killed_and_resumed["dirs"][1]
    d = tmp_path / "a"
    shutil.copytree(src, d)
    assert check_attempt(d, {"attempt": 1}).state == "complete"
    assert check_attempt(d, {"attempt": 2}).problems == ["attempt is 1, expected 2"]
    # a model named after the agent that played it (an unnamed MCP configuration) is not a mismatch
    res = json.loads((d / "result.json").read_text())
    (d / "result.json").write_text(json.dumps({**res, "model": "mcp:some-client", "agent": {
        "kind": "mcp_client", "named_by": "client", "client": None, "clients": []}}))
    assert check_attempt(d, {"attempt": 1, "model": "mcp_client"}).state == "complete"
    (d / "result.json").write_text(json.dumps({**res, "model": "mcp:some-client"}))
    assert check_attempt(d, {"attempt": 1, "model": "mcp_client"}).problems == [
        "model is 'mcp:some-client', expected 'mcp_client'"]
    (d / "result.json").write_text(json.dumps(res))
    lines = (d / "events.jsonl").read_text().splitlines(keepends=True)
    (d / "events.jsonl").write_text("".join(lines[:-1]))
    assert check_attempt(d).problems == ["events.jsonl does not end with attempt_end"]
    (d / "result.json").write_text('{"record_version": "cab-record/1", "task"')
    assert check_attempt(d).state == "partial"
    assert check_attempt(tmp_path / "empty").state == "absent"


def test_config_diff_names_each_changed_key():
    old = {"model": {"name": "oracle", "t": 0.0}, "record": {"video": True}}
    new = {"model": {"name": "oracle", "t": 0.7}, "record": {}, "seed": 3}
    assert config_diff(old, new) == ["model.t: 0.0 -> 0.7", "record.video removed (was True)", "seed added (3)"]
    assert fingerprint(old, [["attempt=1"]]) == fingerprint(json.loads(json.dumps(old)), [["attempt=1"]])
    assert fingerprint(old, [["attempt=1"]]) != fingerprint(new, [["attempt=1"]])


def _descends_from(pid: int, root: int) -> bool:
    while pid > 1:
        if pid == root:
            return True
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            return False
    return False


def attempt_in_flight(root: int) -> tuple[Path, int] | None:
    """(attempt dir, pid of the worker supervising it) of an attempt process of the sweep ``root``
    that is recording: found by the event log it holds open."""
    for proc in Path("/proc").iterdir():
        try:
            if not proc.name.isdigit() or b"cab_core.sweep.worker" not in (proc / "cmdline").read_bytes():
                continue
            if not _descends_from(int(proc.name), root):
                continue
            for fd in (proc / "fd").iterdir():
                target = Path(os.readlink(fd))
                if target.name == "events.jsonl":
                    ppid = int((proc / "stat").read_text().rsplit(")", 1)[1].split()[1])
                    return target.parent, ppid
        except (OSError, ValueError):
            continue
    return None


@pytest.mark.sim
@pytest.mark.slow
def test_ray_worker_killed_loses_only_its_attempt_in_flight(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_ray_launcher")
    sweep = tmp_path / "sw"
    # sweep.fork_workers=false: the attempt's process is then a child of the Ray worker supervising it, which
    # is how attempt_in_flight finds that worker (a forked worker is the fork server's child, and dies with
    # its supervisor through a pidfd: test_worker_memory.py)
    proc = subprocess.Popen([CAB, "-m", "hydra/launcher=ray_local", "hydra.launcher.ray.init.num_cpus=2",
                             "task=beat_block_hammer", "model=scripted", f"model.script={busy_script(tmp_path)}",
                             "attempt=1,2,3", "record.video=false", "sweep.fork_workers=false",
                             f"hydra.sweep.dir={sweep}"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline, hit = time.monotonic() + 300, None
        while hit is None and time.monotonic() < deadline and proc.poll() is None:
            hit = attempt_in_flight(proc.pid)
            time.sleep(0.2)
        assert hit is not None, "no attempt in flight was found"
        os.kill(hit[1], signal.SIGKILL)  # the Ray worker running that job; Ray runs the job again
        out, err = proc.communicate(timeout=600)
    finally:
        end_group(proc)
    assert proc.returncode == 0, err[-3000:]
    for a, d in attempt_dirs(sweep).items():
        if a > 3:
            continue
        assert check_attempt(d, {"attempt": a, "model": "scripted"}, "cli.log").state == "complete"
        aside = sorted(p.name for p in (d / "set_aside").iterdir()) if (d / "set_aside").exists() else []
        assert aside == (["01-interrupted"] if d.resolve() == hit[0] else [])
    m = json.loads((sweep / MANIFEST).read_text())
    assert m["sessions"][0]["launcher"] == "hydra_plugins.hydra_ray_launcher.ray_launcher.RayLauncher"
    assert sum("cab sweep [" in line for line in (out + err).splitlines()) == 3


@pytest.mark.parametrize("launcher, target, settings", [
    ("local", "hydra_plugins.cab_launcher.local_launcher.LocalLauncher",
     {"n_jobs": "${cab.in_flight:${sweep.max_in_flight}}", "stagger_s": 0.25}),  # the default: attempts in flight (tests/test_inflight.py)
    ("joblib", "hydra_plugins.hydra_joblib_launcher.joblib_launcher.JoblibLauncher", {"n_jobs": -1}),
    ("ray_local", "hydra_plugins.hydra_ray_launcher.ray_launcher.RayLauncher",
     {"ray": {"init": {"address": None, "num_cpus": None, "include_dashboard": False}, "remote": {"num_cpus": 1}}}),
    ("slurm", "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher",
     {"cpus_per_task": 2, "mem_gb": 8, "timeout_min": 240, "array_parallelism": 64, "name": "cab"}),
])
def test_launcher_configs_compose(launcher, target, settings):
    from omegaconf import OmegaConf

    pytest.importorskip(target.rsplit(".", 2)[0])
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        overrides = [] if launcher == "local" else [f"hydra/launcher={launcher}"]  # local is the default
        cfg = compose(config_name="config", overrides=overrides, return_hydra_config=True)
    got = OmegaConf.to_container(cfg.hydra.launcher, resolve=False)
    assert got["_target_"] == target
    assert {k: got[k] for k in settings} == settings


# -- infrastructure failures ----------------------------------------------------------------------

def composed(*overrides: str) -> dict:
    from omegaconf import OmegaConf

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(list(overrides)))
    return OmegaConf.to_container(cfg, resolve=True)


IDENTITY = {"task": "beat_block_hammer", "seed": 0, "attempt": 1, "sim": "sapien", "model": "idle"}


class Saboteur:
    """Breaks the first tries' processes for real once they have started recording: SIGKILL (a
    simulator crash) or SIGSTOP (a hang the watchdog must catch)."""

    def __init__(self, attempt_dir: Path, plan: dict[int, signal.Signals]):
        self.dir, self.plan, self.threads, self.environ = attempt_dir, plan, [], []

    def __call__(self, proc: subprocess.Popen, try_no: int) -> None:
        environ, deadline = b"", time.monotonic() + 10
        while not environ and time.monotonic() < deadline:  # empty until exec has set the new one up
            environ = Path(f"/proc/{proc.pid}/environ").read_bytes()
        self.environ.append(environ.split(b"\0"))
        if try_no in self.plan:
            t = threading.Thread(target=self._strike, args=(proc, self.plan[try_no]), daemon=True)
            t.start()
            self.threads.append(t)

    def _strike(self, proc: subprocess.Popen, sig: signal.Signals) -> None:
        while proc.poll() is None and not (self.dir / "events.jsonl").exists():
            time.sleep(0.05)
        if proc.poll() is None:
            os.kill(proc.pid, sig)


@pytest.mark.sim
@pytest.mark.slow
def test_crash_and_hang_are_retried_and_recorded(tmp_path):
    d = tmp_path / "a"
    sab = Saboteur(d, {1: signal.SIGKILL, 2: signal.SIGSTOP})
    settings = SupervisorConfig.from_cfg({"max_infra_retries": 2, "hang_timeout_s": 30, "retry_backoff_s": 0})
    res = AttemptSupervisor(composed("model=idle", "record.video=false"), d, IDENTITY, settings, on_child=sab).run()
    assert not is_infrastructure_failure(res)
    assert res["verdict"]["success"] is False and res["termination"]["reason"] == "done"
    fails = infrastructure_failures(d)
    assert [f["kind"] for f in fails] == ["crash", "hang"]
    assert fails[0]["detail"] == "attempt process killed by signal 9"
    assert [f["records"] for f in fails] == ["set_aside/01-crash", "set_aside/02-hang"]
    assert res["infrastructure"] == {"failed": False, "failures": fails}
    for f in fails:
        assert (d / f["records"] / "events.jsonl").exists() and not (d / f["records"] / "result.json").exists()
    assert check_attempt(d, IDENTITY).state == "complete"
    for env in sab.environ:  # one core's worth of renderer and BLAS threads per attempt (sweep default)
        assert {b"LP_NUM_THREADS=1", b"OMP_NUM_THREADS=1", b"OPENBLAS_NUM_THREADS=1"} <= set(env)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.sim
@pytest.mark.slow
def test_provider_outage_is_an_infrastructure_failure_not_the_models(tmp_path):
    d = tmp_path / "a"
    cfg = composed("model=qwen_local", f"model.base_url=http://127.0.0.1:{_closed_port()}/v1",
                   "model.retry.max_attempts=1", "record.video=false")
    ident = {**IDENTITY, "model": "qwen_local"}
    res = AttemptSupervisor(cfg, d, ident, SupervisorConfig(max_retries=1, retry_backoff_s=0.0)).run()
    assert is_infrastructure_failure(res)
    assert res["verdict"] == {"success": None, "excluded": "infrastructure_failure"}
    fails = res["infrastructure"]["failures"]
    assert [f["kind"] for f in fails] == ["provider_failure", "provider_failure"]
    for f in fails:  # each try's full record is kept, with the harness's own account of the outage
        kept = json.loads((d / f["records"] / "result.json").read_text())
        assert kept["termination"]["reason"] == "provider_failure"
    assert check_attempt(d, ident).state == "partial"


def test_the_default_fork_planner_leaves_a_sweeps_fingerprint_as_before():
    """fork.planner (issue 30) at its default: a sweep begun before the key existed resumes."""
    from omegaconf import OmegaConf

    from cab_core.sweep.manifest import _stable_config

    before = {"task": {"name": "click_bell"}, "fork": {"from": None, "at": None}}
    now = {**before, "fork": {"from": None, "at": None, "planner": "parent"}}
    assert _stable_config(OmegaConf.create(now)) == _stable_config(OmegaConf.create(before))
    own = {**before, "fork": {"from": "d", "at": 3, "planner": "own"}}
    assert _stable_config(OmegaConf.create(own))["fork"] == {"from": "d", "at": 3, "planner": "own"}
