"""Two pieces every plugin package writes alike, for plugins of this tree and third-party ones:

* :func:`config_dirs_hook` builds the ``cab_config_dirs`` hook implementation that hands Hydra the
  plugin's option files (``<package>/conf/<group>/<option>.yaml``)::

      cab_config_dirs = config_dirs_hook("my_plugin")

* :func:`missing_dependency` turns the ``ImportError`` of a heavy optional dependency, imported
  when a factory is called rather than when cab loads the plugin, into
  :class:`~cab_core.errors.MissingDependency`, whose message carries the install command::

      def create_simulator(cfg=None):
          with missing_dependency("MySim", "pip install mysim", "mysim"):
              from .simulator import MySimulator
          return MySimulator(cfg)
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager

from cab_core.contracts.hookspecs import hookimpl
from cab_core.errors import MissingDependency


def config_dirs_hook(package: str) -> Callable[[], list[str]]:
    """The ``cab_config_dirs`` hook implementation of the plugin package ``package``: it returns
    ``["pkg://<package>.conf"]``. Assign it to the name ``cab_config_dirs`` in the module the entry
    point names, so that pluggy finds it there."""

    @hookimpl
    def cab_config_dirs() -> list[str]:
        """This plugin's option files for Hydra (``conf/<group>/<option>.yaml``)."""
        return [f"pkg://{package}.conf"]

    return cab_config_dirs


@contextmanager
def missing_dependency(what: str, install: str, *roots: str) -> Iterator[None]:
    """Within the block, an ``ImportError`` of a module under one of the top-level packages
    ``roots`` is raised again as ``MissingDependency(what, install)``; any other ``ImportError``
    (one of the plugin's own modules, say) passes through unchanged."""
    try:
        yield
    except ImportError as e:  # pragma: no cover - depends on the environment
        if e.name and e.name.split(".")[0] in roots:
            raise MissingDependency(what, install) from e
        raise
