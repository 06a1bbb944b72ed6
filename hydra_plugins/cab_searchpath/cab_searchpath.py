"""Hydra search path plugins of the ``cab`` distribution (Hydra discovers every module under the
``hydra_plugins`` namespace package). Both act only on cab's own search path and import nothing
heavy until Hydra calls them.

* :class:`CabPluginConfigs`: the installed plugins' config dirs and tasks (cab_core.config);
* :class:`CabProjectConfig`: the project's composition (the checkout's ``conf/``, installed as the
  package ``cab_conf``) before the core's primary config, so that its ``config.yaml`` is the one
  composed, where it is installed.
"""
from __future__ import annotations

from hydra.core.config_search_path import ConfigSearchPath, SearchPathQuery
from hydra.plugins.search_path_plugin import SearchPathPlugin

PROJECT_PACKAGE = "cab_conf"


class CabPluginConfigs(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        # here, not at the top: Hydra imports every hydra_plugins module in any Hydra application, and
        # cab_core.config (with the configuration schema and the plugin registry) adds 0.06 s to Hydra's
        # own imports (python -X importtime -c "import hydra, cab_core.config")
        from cab_core.config import extend_search_path

        extend_search_path(search_path)


class CabProjectConfig(SearchPathPlugin):
    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        import importlib.util

        from cab_core.config import is_cab_search_path  # at first use, as above

        if not is_cab_search_path(search_path) or importlib.util.find_spec(PROJECT_PACKAGE) is None:
            return
        path = f"pkg://{PROJECT_PACKAGE}"
        if all(e.path != path for e in search_path.get_path()):
            search_path.prepend("cab-project", path, anchor=SearchPathQuery(provider="main"))
