"""The conformance suites' pytest plugin (cab_core.testing.pytest_plugin, entry point pytest11 ``cab``),
run in-process by pytester against plugin registries made up here: ``--cab-conformance`` collects
every installed simulator x check and task x simulator, the restrictions narrow that, mistakes are
usage errors, a failing check fails, the task items' attempts run in one batch of the selected
pairs, and without the option nothing is added."""
from __future__ import annotations

import json

import pytest

from cab_core import hookimpl, plugins
from cab_core.testing import sim_conformance as sc
from cab_core.testing import task_conformance as tc

pytest_plugins = ["pytester"]

ALL_CHECKS = [sc.check_id(c) for c in sc.CHECKS]
NO_PICTURES = [sc.check_id(c) for c in sc.CHECKS if c not in sc.NEEDS_RENDERER]


class FakeWorldPlugins:
    """Simulators ``alpha`` and ``beta`` (never built while collecting) and tasks ``t1``, ``t2``."""

    def __init__(self, simulators=None):
        self.simulators = simulators or {"alpha": _never, "beta": _never}

    @hookimpl
    def cab_simulators(self):
        return self.simulators

    @hookimpl
    def cab_task_suites(self):
        return {"fake_suite": lambda: {"t1": object(), "t2": object()}}


def _never(cfg):
    raise AssertionError("a simulator was built while collecting")


@pytest.fixture
def registered(monkeypatch):
    """Use these plugins instead of the installed ones, in this process (pytester runs in it)."""
    def use(*extra):
        monkeypatch.setattr(plugins, "plugin_manager", lambda: plugins.build_plugin_manager(extra=list(extra),
                                                                                          autoload=False))
    return use


@pytest.fixture
def project(pytester):
    pytester.makepyfile(test_own="def test_own():\n    pass\n")
    return pytester


def collected(pytester, *args) -> list[str]:
    """The node ids of the session's items (after -k)."""
    rec = pytester.inline_run("-p", "no:cacheprovider", "--collect-only", *args)
    assert rec.ret in (0, pytest.ExitCode.NO_TESTS_COLLECTED), rec.ret
    [finish] = rec.getcalls("pytest_collection_finish")
    return [i.nodeid for i in finish.session.items]


def test_the_option_off_adds_nothing(project, registered):
    registered(FakeWorldPlugins())
    assert collected(project) == ["test_own.py::test_own"]


def test_every_installed_simulator_and_task_is_collected(project, registered):
    registered(FakeWorldPlugins())
    got = collected(project, "--cab-conformance")
    sims = ["alpha", "beta"]
    want = (["test_own.py::test_own"]
            + [f"cab-conformance::test_simulator[{s}-{c}]" for s in sims for c in ALL_CHECKS]
            + [f"cab-conformance::test_simulator_physics_only[{s}-{c}]" for s in sims for c in NO_PICTURES]
            + [f"cab-conformance::test_simulator_render_independent[{s}]" for s in sims]
            + [f"cab-conformance::test_task[{t}-{s}]" for t in ("t1", "t2") for s in sims]
            + [f"cab-conformance::test_task_determinism[{t}-{s}]" for t in ("t1", "t2") for s in sims])
    assert got == want
    assert len(ALL_CHECKS) >= 12 and "snapshot_restore_exact" in ALL_CHECKS and "cameras" not in NO_PICTURES


def test_groups_and_restrictions(project, registered):
    registered(FakeWorldPlugins())
    got = collected(project, "--cab-conformance=sims", "--cab-sims=beta", "-k", "not test_own")
    assert got == ([f"cab-conformance::test_simulator[beta-{c}]" for c in ALL_CHECKS]
                   + [f"cab-conformance::test_simulator_physics_only[beta-{c}]" for c in NO_PICTURES]
                   + ["cab-conformance::test_simulator_render_independent[beta]"])
    got = collected(project, "--cab-conformance=tasks", "--cab-tasks=t2", "-k", "not test_own")
    assert got == ["cab-conformance::test_task[t2-alpha]", "cab-conformance::test_task[t2-beta]"]
    got = collected(project, "--cab-conformance=determinism", "--cab-sims=alpha", "-k", "not test_own")
    assert got == ["cab-conformance::test_task_determinism[t1-alpha]", "cab-conformance::test_task_determinism[t2-alpha]"]
    got = collected(project, "--cab-conformance=sims,tasks", "--cab-sims=alpha", "--cab-tasks=t1", "-k", "t1 or timestep")
    assert got == ["cab-conformance::test_simulator[alpha-timestep]",
                   "cab-conformance::test_simulator_physics_only[alpha-timestep]",
                   "cab-conformance::test_task[t1-alpha]"]


def test_nothing_installed_is_one_skip_that_says_so(project, registered):
    registered()
    result = project.runpytest_inprocess("-p", "no:cacheprovider", "--cab-conformance", "-rs", "-k", "not test_own")
    result.assert_outcomes(skipped=5)
    result.stdout.fnmatch_lines(["*no simulator selected or installed*"])


@pytest.mark.parametrize("args, message", [
    (["--cab-conformance", "--cab-sims=gamma"], "--cab-sims: unknown simulator gamma; installed: alpha, beta"),
    (["--cab-conformance", "--cab-tasks=t1,t9"], "--cab-tasks: unknown task t9; installed: t1, t2"),
    (["--cab-conformance=simz"], "--cab-conformance: unknown group simz; groups: sims, tasks, determinism, all*"),
    (["--cab-conformance", "test_own.py"], "--cab-conformance: unknown group test_own.py;*"),
    (["--cab-sims=alpha"], "--cab-sims needs --cab-conformance"),
    (["--cab-conformance", "--cab-jobs=0"], "--cab-jobs must be at least 1, got 0"),
])
def test_mistakes_are_usage_errors(project, registered, args, message):
    registered(FakeWorldPlugins())
    result = project.runpytest_inprocess("-p", "no:cacheprovider", *args)
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines([f"ERROR: {message}"])


def test_a_failing_check_fails(project, registered):
    """A simulator that lies about its timestep fails the timestep check, with and without pictures;
    the real one beside it passes."""
    pytest.importorskip("mujoco")
    from cab_sim_mujoco.simulator import MujocoSimulator  # after the skip: MuJoCo may not be installed

    class Liar(MujocoSimulator):
        @property
        def timestep(self):
            return 2 * super().timestep

    registered(FakeWorldPlugins({"mujoco": MujocoSimulator, "liar": Liar}))
    rec = project.inline_run("-p", "no:cacheprovider", "--cab-conformance=sims", "-k", "timestep")
    passed, skipped, failed = rec.listoutcomes()
    assert sorted(r.nodeid for r in failed) == ["cab-conformance::test_simulator[liar-timestep]",
                                                "cab-conformance::test_simulator_physics_only[liar-timestep]"]
    assert sorted(r.nodeid for r in passed) == ["cab-conformance::test_simulator[mujoco-timestep]",
                                                "cab-conformance::test_simulator_physics_only[mujoco-timestep]"]
    assert not skipped
    assert all("def check_timestep" in str(r.longrepr) and "AssertionError" in str(r.longrepr) for r in failed)


def _rows(tmp_path, task, sim, oracle_success=True, idle_success=False) -> tc.PairResult:
    rows = {}
    for agent, success in (("oracle", oracle_success), ("idle", idle_success)):
        d = tmp_path / task / sim / agent
        d.mkdir(parents=True)
        held = success
        verdict = {"predicates": {"near": held}, "final_requirements": {}, "guard": {}, "margins_at": "final",
                   "margins": {"near": {"slack": 0.01 if held else -0.01, "scale": 0.02,
                                        "fraction": 0.5 if held else -0.5}},
                   "margin": {"predicate": "near", "fraction": 0.5 if held else -0.5, "borderline": False,
                              "threshold": 0.02}}
        (d / "result.json").write_text(json.dumps({"verdict": verdict}))
        rows[agent] = {"task": task, "sim": sim, "agent": agent, "dir": str(d), "success": success,
                       "termination": "done", "margin": verdict["margin"]["fraction"], "calls": 5,
                       "calls_limit": 28, "sim_s": 5.0, "sim_s_limit": 60.0, "subgoals": [success],
                       "subgoals_at_start": [False], "checkpoint_error": None}
    return tc.PairResult(task, sim, rows)


def test_task_items_run_the_selected_pairs_in_one_batch(project, registered, monkeypatch, tmp_path):
    """The first task item runs the attempts of every task item left after -k, once; each item
    then judges its own pair (t1 on beta: the oracle failed)."""
    registered(FakeWorldPlugins())
    batches = []

    def run_attempts(pairs, jobs, out):
        batches.append((list(pairs), jobs))
        return {(t, s): _rows(tmp_path, t, s, oracle_success=(t, s) != ("t1", "beta")) for t, s in pairs}

    monkeypatch.setattr(tc, "run_attempts", run_attempts)
    rec = project.inline_run("-p", "no:cacheprovider", "--cab-conformance=tasks", "--cab-jobs=3", "-k", "t1")
    passed, _, failed = rec.listoutcomes()
    assert batches == [([("t1", "alpha"), ("t1", "beta")], 3)]
    assert [r.nodeid for r in passed] == ["cab-conformance::test_task[t1-alpha]"]
    assert [r.nodeid for r in failed] == ["cab-conformance::test_task[t1-beta]"]
    assert "t1 on beta: the oracle failed (done)" in str(failed[0].longrepr)


@pytest.mark.parametrize("change, message", [
    (dict(oracle_success=False), "the oracle failed"),
    (dict(idle_success=True), "the idle agent succeeded"),
])
def test_check_pair_fails_a_failing_oracle_or_a_succeeding_idle_agent(tmp_path, change, message):
    res = _rows(tmp_path, "t1", "alpha", **change)
    with pytest.raises(AssertionError, match=message):
        tc.check_pair(res)


def test_check_pair_refuses_over_budget_errors_and_subgoals_at_start(tmp_path):
    tc.check_pair(_rows(tmp_path / "ok", "t1", "alpha"))  # the made-up records pass as they are
    for edit, message in ((lambda r: r["oracle"].update(calls=29), "used 29 calls of 28"),
                          (lambda r: r["oracle"].update(sim_s=61.0), "simulated s of 60"),
                          (lambda r: r["oracle"].update(subgoals=[True, False]), "subgoals attained"),
                          (lambda r: r["idle"].update(subgoals_at_start=[True]), "a subgoal holds at the start"),
                          (lambda r: r["idle"].update(error="infrastructure failure: x"), "idle attempt failed"),
                          (lambda r: r.pop("idle"), "the idle attempt did not run")):
        res = _rows(tmp_path / message.replace(" ", "_"), "t1", "alpha")
        edit(res.rows)
        with pytest.raises(AssertionError, match=message):
            tc.check_pair(res)


@pytest.mark.sim
def test_determinism_check_fails_a_restore_that_restores_nothing(tmp_path, monkeypatch):
    """The check passes on MuJoCo's world of click_bell, and fails once restore_state is a no-op."""
    pytest.importorskip("mujoco")
    from cab_sim_mujoco.simulator import MujocoSimulator  # after the skip: MuJoCo may not be installed

    tc.check_determinism_and_restore("click_bell", "mujoco", tmp_path / "real")
    monkeypatch.setattr(MujocoSimulator, "restore_state", lambda self, state: None)
    with pytest.raises(AssertionError, match="click_bell on mujoco: qpos differs after restore_state"):
        tc.check_determinism_and_restore("click_bell", "mujoco", tmp_path / "broken")


def test_a_batch_that_cannot_run_fails_its_items_without_running_again(project, registered, monkeypatch):
    registered(FakeWorldPlugins())
    calls = []

    def run_attempts(pairs, jobs, out):
        calls.append(list(pairs))
        raise RuntimeError("no Hydra config for simulator alpha")

    monkeypatch.setattr(tc, "run_attempts", run_attempts)
    rec = project.inline_run("-p", "no:cacheprovider", "--cab-conformance=tasks", "--cab-sims=alpha", "-k", "not test_own")
    passed, _, failed = rec.listoutcomes()
    assert calls == [[("t1", "alpha"), ("t2", "alpha")]] and not passed
    assert [r.nodeid for r in failed] == ["cab-conformance::test_task[t1-alpha]", "cab-conformance::test_task[t2-alpha]"]
    assert all("no Hydra config for simulator alpha" in str(r.longrepr) for r in failed)
