"""Entry point of the Every Eval Ever export (group ``cab``): the sweep exporter ``eee`` of
``cab-export``. every-eval-ever is imported only when a sweep is exported, so listing plugins stays
cheap and a missing package is one line with the install command."""
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cab_core.contracts.hookspecs import hookimpl
from cab_core.errors import MissingDependency

INSTALL = "pip install 'every-eval-ever>=0.3.0,<0.4' (Python >= 3.12)"


def export(sweep: Mapping[str, Any], out_dir: os.PathLike) -> list[Path]:
    """``cab-export eee``: the sweep (cab's sweep data, hook ``cab_sweep_exporters``) as EEE records
    below ``<out_dir>/data/``."""
    try:
        import every_eval_ever  # noqa: F401
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise MissingDependency("every-eval-ever", INSTALL) from e
    from .convert import export_sweep

    return export_sweep(sweep, Path(out_dir))


@hookimpl
def cab_sweep_exporters():
    return {"eee": export}
