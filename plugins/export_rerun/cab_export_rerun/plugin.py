"""Entry point of the Rerun export (group ``cab``): the record observer ``rerun`` and the exporter
``rerun`` of ``cab-export``. Both write an attempt as ``attempt.rrd`` with :func:`.convert.convert`.

The observer is off unless ``record.observers`` names it (``record.observers=[rerun]``): writing the
recording costs more than a second per attempt (``docs/export.md``). rerun-sdk is imported only when
an observer is created or a record exported, so listing plugins stays cheap and a missing SDK is one
line with the install command."""
from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cab_core.contracts.hookspecs import hookimpl
from cab_core.errors import ConfigError, MissingDependency

INSTALL = "pip install 'rerun-sdk>=0.41' 'pyarrow>=18'"


def _require_sdk() -> None:
    try:
        import rerun  # noqa: F401
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise MissingDependency("the Rerun SDK (rerun-sdk)", INSTALL) from e


class RerunObserver:
    """Writes ``attempt.rrd`` once the attempt's record is complete (``on_result``): the snapshots
    of a call are written after its event and the video is rendered after the last one, so the
    recording is made from the finished folder. Config: ``video`` (default true), ``file`` (default
    ``attempt.rrd``, relative to the attempt's folder)."""

    KEYS = ("video", "file")

    def __init__(self, cfg: Mapping[str, Any]):
        unknown = sorted(set(cfg) - {*self.KEYS, "name", "attempt_dir"})
        if unknown:
            raise ConfigError(f"record.observers.rerun: unknown key(s) {', '.join(unknown)}; valid: {', '.join(self.KEYS)}")
        _require_sdk()
        self.dir = Path(cfg["attempt_dir"])
        self.video = bool(cfg.get("video", True))
        self.file = self.dir / str(cfg.get("file") or "attempt.rrd")

    def on_result(self, result: Mapping[str, Any]) -> None:
        # here and in export(), not at the top: cab loads every plugin at start-up, and the
        # converter costs 0.7 s (python -X importtime on top of cab_core.plugins, 2026-11-27)
        from .convert import convert

        convert(self.dir, self.file, video=self.video)


RerunObserver.on_by_default = False  # costs more than a second an attempt: only when record.observers names it


def export(attempt_dir: os.PathLike, out_dir: os.PathLike) -> list[Path]:
    """``cab-export rerun``: ``<out_dir>/attempt.rrd`` from the finished attempt in ``attempt_dir``."""
    _require_sdk()
    from .convert import FILE, convert

    return [convert(attempt_dir, Path(out_dir) / FILE)]


@hookimpl
def cab_record_observers():
    return {"rerun": RerunObserver}


@hookimpl
def cab_record_exporters():
    return {"rerun": export}
