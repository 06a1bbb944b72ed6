"""Conformance suites for plugin authors.

* :mod:`cab_core.testing.sim_conformance` -- the checks every simulator backend passes;
* :mod:`cab_core.testing.task_conformance` -- the checks every task passes on every simulator
  (its oracle succeeds within budgets at the catalog seed, the idle agent fails);
* :mod:`cab_core.testing.pytest_plugin` -- both, as a pytest plugin (``pytest --cab-conformance``),
  parametrised over what is installed (a ``pytest11`` entry point of the core distribution).
"""
