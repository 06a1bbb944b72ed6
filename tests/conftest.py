# cab_core first: it pins the numerics (cab_core.numerics) before anything imports numpy, so the tests
# run with the settings every attempt process has.
import cab_core  # noqa: F401, I001 (first, on purpose)
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
