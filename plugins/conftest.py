"""Fixtures of the plugins' own tests (``plugins/<plugin>/tests/``), which pytest collects with the core's
(``testpaths`` in pyproject.toml). The helpers they share with the core's tests (``sim_backend_checks``)
are found in ``tests/`` (``pythonpath`` there)."""
# cab_core first: it pins the numerics (cab_core.numerics) before anything imports numpy, so the tests
# run with the settings every attempt process has.
import cab_core  # noqa: F401, I001

import pytest


@pytest.fixture(scope="module")
def aloha_spec(tmp_path_factory):
    """The aloha_agilex embodiment (default parameters), its generated files in a cache of this
    module's own."""
    # here, not at the top: every plugin's tests load this file, and only the aloha and mplib tests need
    # the embodiment plugin installed
    from cab_embodiment_aloha import embodiment

    mp = pytest.MonkeyPatch()
    mp.setenv("CAB_CACHE_DIR", str(tmp_path_factory.mktemp("cache")))
    try:
        yield embodiment.factory({})
    finally:
        mp.undo()
