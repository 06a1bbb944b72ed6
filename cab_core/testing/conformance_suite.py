"""The checks ``pytest --cab-conformance`` adds (collected by :mod:`cab_core.testing.pytest_plugin`
under the node id ``cab-conformance``; not a test module of its own: its name does not start with
``test_``). Parametrised here, from the plugin's selection, over the installed simulators and tasks."""
from __future__ import annotations

from collections.abc import Callable

import pytest

from cab_core.plugins import registry
from cab_core.testing import sim_conformance as sc
from cab_core.testing import task_conformance as tc
from cab_core.testing.selection import selection


def _sim_factory(name: str, render: bool) -> Callable:
    factory = registry("simulators")[name]
    return lambda: factory({"name": name, "render": render})


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    sel = selection(metafunc.config)
    sims = sel.sims if sel is not None else ()
    tasks = sel.tasks if sel is not None else ()
    name = metafunc.function.__name__
    if name == "test_simulator_render_independent":
        metafunc.parametrize("cab_sim", [pytest.param(s, id=s) for s in sims] or [
            pytest.param(None, id="none", marks=pytest.mark.skip(reason="no simulator selected or installed"))])
    elif name in ("test_simulator", "test_simulator_physics_only"):
        checks = sc.CHECKS if name == "test_simulator" else [c for c in sc.CHECKS if c not in sc.NEEDS_RENDERER]
        params = [pytest.param(s, c, id=f"{s}-{sc.check_id(c)}") for s in sims for c in checks]
        metafunc.parametrize(("cab_sim", "cab_check"), params or [
            pytest.param(None, None, id="none", marks=pytest.mark.skip(reason="no simulator selected or installed"))])
    elif name in ("test_task", "test_task_determinism"):
        params = [pytest.param(t, s, id=f"{t}-{s}") for t in tasks for s in sims]
        metafunc.parametrize(("cab_task", "cab_sim"), params or [
            pytest.param(None, None, id="none",
                         marks=pytest.mark.skip(reason="no task or no simulator selected or installed"))])


@pytest.fixture(scope="session")
def cab_render_diagnosis() -> Callable[[str], str | None]:
    """``diagnosis(sim)``: None where the simulator renders on this machine, else why not (once per
    simulator and session)."""
    seen: dict[str, str | None] = {}

    def diagnosis(sim: str) -> str | None:
        if sim not in seen:
            seen[sim] = sc.render_diagnosis(_sim_factory(sim, True))
        return seen[sim]

    return diagnosis


def test_simulator(cab_sim: str, cab_check: Callable, cab_render_diagnosis) -> None:
    """A conformance check on a rendering build; where the simulator cannot render here, on a
    physics-only build (and the checks that take pictures are skipped with the diagnosis)."""
    why = cab_render_diagnosis(cab_sim)
    if why is None:
        cab_check(_sim_factory(cab_sim, True))
    elif cab_check in sc.NEEDS_RENDERER:
        pytest.skip(f"{cab_sim} needs a renderer: {why}")
    else:
        cab_check(_sim_factory(cab_sim, False))


def test_simulator_physics_only(cab_sim: str, cab_check: Callable) -> None:
    """Everything but pictures also holds on a physics-only build (``render: false``)."""
    cab_check(_sim_factory(cab_sim, False))


def test_simulator_render_independent(cab_sim: str, cab_render_diagnosis) -> None:
    """A rendering build and a physics-only build of one world step alike."""
    why = cab_render_diagnosis(cab_sim)
    if why is not None:
        pytest.skip(f"{cab_sim} needs a renderer: {why}")
    sc.check_physics_independent_of_rendering(_sim_factory(cab_sim, True), _sim_factory(cab_sim, False))


@pytest.fixture(scope="session")
def cab_task_results(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    """``results(task, sim)``: the suite check's rows of that pair. The first call runs the attempts
    of every ``test_task`` item of this session (those left after ``-k``/``-m``) in one batch."""
    cache: dict[tuple[str, str], tc.PairResult] = {}
    broken: dict[tuple[str, str], BaseException] = {}  # a batch that could not run fails its items once
    sel = selection(request.config)

    def results(task: str, sim: str) -> tc.PairResult:
        if (task, sim) in broken:
            raise RuntimeError(f"the batch of task attempts with {task} on {sim} could not run") from broken[(task, sim)]
        if (task, sim) not in cache:
            pairs = []
            for item in request.session.items:
                cs = getattr(item, "callspec", None)
                if getattr(item, "originalname", "") == "test_task" and cs is not None and cs.params.get("cab_task"):
                    pair = (cs.params["cab_task"], cs.params["cab_sim"])
                    if pair not in cache and pair not in pairs:
                        pairs.append(pair)
            if (task, sim) not in pairs:
                pairs.append((task, sim))
            try:
                cache.update(tc.run_attempts(pairs, sel.jobs if sel else 1, tmp_path_factory.mktemp("cab-tasks")))
            except Exception as e:
                broken.update((p, e) for p in pairs)
                raise
        return cache[(task, sim)]

    return results


def test_task(cab_task: str, cab_sim: str, cab_task_results) -> None:
    """At the catalog seed the oracle succeeds within budgets, attaining every subgoal, and the idle
    agent fails with no subgoal satisfied at the start; both verdicts record consistent margins."""
    tc.check_pair(cab_task_results(cab_task, cab_sim))


def test_task_determinism(cab_task: str, cab_sim: str, tmp_path) -> None:
    """Two builds of the task's world give identical privileged snapshots after settling and after
    the same motion; a saved state restores exactly and replays the motion."""
    tc.check_determinism_and_restore(cab_task, cab_sim, tmp_path)
