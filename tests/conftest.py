# cab_core first: it pins the numerics (cab_core.numerics) before anything imports numpy, so the tests
# run with the settings every attempt process has.
import cab_core  # noqa: F401, I001 (first, on purpose)
import os

import pytest


@pytest.fixture(scope="session")
def task_builds(tmp_path_factory):
    """The suite's task instances at suite_helpers.SEEDS, built once a session on first use
    (suite_helpers.Builds): ``task_builds[name][i]`` is task ``name`` at seed ``SEEDS[i]``."""
    from suite_helpers import Builds, cache_dir

    return Builds(cache_dir(tmp_path_factory))


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The session's shared sweep of real attempts (attempt_records.shared_sweep: built once, by the
    first test module that asks for it); a module that needs a sweep of its own defines this fixture."""
    from attempt_records import shared_sweep

    return shared_sweep(tmp_path_factory)


@pytest.fixture
def process_plugins():
    """``process_plugins(module, name)`` registers ``module`` in the process's plugin manager
    (cab_core.plugins.plugin_manager()) as an installed plugin would be, until the test ends."""
    from cab_core.plugins import plugin_manager

    pm = plugin_manager()
    names: list[str] = []

    def register(module, name: str) -> None:
        pm.register(module, name=name)
        names.append(name)

    yield register
    for name in reversed(names):
        pm.unregister(name=name)


# Under pytest-xdist (scripts/test.sh: `-n <cpus> --dist loadfile`) each worker has a session of its own, and
# the unit a worker takes is a test file (its module-scoped fixtures built once, its tests in their order),
# or, for the conformance items (all under one node), one check: test_task's items together, since the
# first of them runs the batch of task attempts of every test_task item of the session. xdist's loadgroup
# would say this with marks, but it ignores them under pytest 9.2 (pytest-xdist issue 1386: it rewrites
# a node id field that pytest no longer reads), so the scheduler is loadfile's with this unit.
@pytest.hookimpl(optionalhook=True)  # a hook of xdist's: pytest without xdist runs the tests as before
def pytest_xdist_make_scheduler(config, log):
    if config.getoption("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class FileOrCheckScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.startswith("cab-conformance::"):
                return nodeid.split("[")[0]
            return nodeid.split("::")[0]

    return FileOrCheckScheduling(config, log)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """In an xdist worker's collection (the order the units are handed out in): the conformance task
    checks first, the longest unit, so their batch starts while the other workers take the files."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        items.sort(key=lambda item: not item.nodeid.startswith("cab-conformance::test_task["))
