"""What every simulator backend guarantees beyond the conformance suite, on each simulator the
plugin registry serves: each check of sim_backend_checks.CHECKS (registration, the common options,
the physics-only mode, snapshots, contacts after a restore, a closed simulator) on each backend.
The shared conformance suite (cab_core.testing.sim_conformance) runs through
`pytest --cab-conformance`; what is particular to one backend is in tests/test_sim_<backend>.py."""
from __future__ import annotations

import pytest
import sim_backend_checks as checks

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module", params=checks.installed())
def backend(request) -> checks.Backend:
    return checks.backend(request.param)


@pytest.mark.parametrize("check", checks.CHECKS, ids=lambda c: c.__name__)
def test_backend_guarantee(backend, check):
    check(backend)
