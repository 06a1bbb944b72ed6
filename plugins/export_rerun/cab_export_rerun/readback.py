"""An ``attempt.rrd`` read back: which entities and components it holds, their static values and
their rows on a timeline, read with rerun-sdk's chunk reader (``rerun.chunk.RrdReader``: the local
reader of Rerun 0.38 and later; ``rerun.dataframe.load_recording`` was removed in 0.29 and
``rerun.recording`` in 0.34). Used to check an export (the plugin's tests, ``tests/test_export.py``)
and to look into one without the viewer::

    from cab_export_rerun.readback import Recording
    rec = Recording("attempt.rrd")
    rec.rows("/world/objects/bell", "Transform3D:translation", "snapshot")

Components are named as Rerun 0.24 and later name them, ``<Archetype>:<field>`` (``Boxes3D:half_sizes``,
``Transform3D:translation``); a value is one component batch (a list: one item per instance).
"""
from __future__ import annotations

import os
from collections import defaultdict
from typing import Any

from cab_core.errors import RecordError

CONTROL = "rerun.controls.RowId"


class Recording:
    """The one recording of an ``.rrd`` file (a file holding none or several is a ``RecordError``)."""

    def __init__(self, path: str | os.PathLike):
        import rerun as rr

        reader = rr.chunk.RrdReader(os.fspath(path))
        stores = reader.recordings()
        if len(stores) != 1:
            raise RecordError(f"{os.fspath(path)}: {len(stores)} recordings in the file, expected one")
        self.application_id, self.recording_id = stores[0].application_id, stores[0].recording_id
        self._static: dict[tuple[str, str], Any] = {}
        # (entity, component) -> [(row id, {timeline: value}, value)]
        self._temporal: dict[tuple[str, str], list[tuple[bytes, dict[str, Any], Any]]] = defaultdict(list)
        for chunk in reader.stream(store=stores[0]).to_chunks():
            batch = chunk.to_record_batch()
            timelines = [n for n in chunk.timeline_names if n in batch.schema.names]
            data = [n for n in batch.schema.names if n != CONTROL and n not in timelines]
            cols = {n: batch.column(n).to_pylist() for n in batch.schema.names}
            for i in range(batch.num_rows):
                for name in data:
                    value = cols[name][i]
                    if value is None:
                        continue
                    key = (chunk.entity_path, name)
                    if chunk.is_static:
                        self._static[key] = value  # chunks come in the order they were written: the last wins
                    else:
                        self._temporal[key].append((cols[CONTROL][i], {t: cols[t][i] for t in timelines}, value))

    @property
    def entities(self) -> set[str]:
        """Every entity path that holds data (``/world/objects/bell``...)."""
        return {e for e, _ in self._static} | {e for e, _ in self._temporal}

    def components(self, entity: str) -> set[str]:
        """The components logged on ``entity`` (``Boxes3D:half_sizes``...), static or on a timeline."""
        return {c for e, c in self._static if e == entity} | {c for e, c in self._temporal if e == entity}

    def archetypes(self, entity: str) -> set[str]:
        """The archetypes logged on ``entity`` (``Boxes3D``, ``Transform3D``...)."""
        return {c.split(":", 1)[0] for c in self.components(entity)}

    def is_static(self, entity: str, component: str) -> bool:
        """Whether ``entity:component`` is static and was never logged on a timeline."""
        return (entity, component) in self._static and (entity, component) not in self._temporal

    def static(self, entity: str, component: str) -> Any:
        """The static value of ``entity:component`` (None: it has none)."""
        return self._static.get((entity, component))

    def _on(self, entity: str, component: str, index: str) -> list[tuple[Any, Any]]:
        rows = [(t[index], row_id, v) for row_id, t, v in self._temporal.get((entity, component), [])
                if t.get(index) is not None]
        return [(at, v) for at, _, v in sorted(rows, key=lambda r: (r[0], r[1]))]

    def rows(self, entity: str, component: str, index: str) -> list:
        """The values of ``entity:component`` logged on the timeline ``index``, one per logged row, in
        the order of the timeline (rows at one time in the order they were logged)."""
        return [v for _, v in self._on(entity, component, index)]

    def times(self, entity: str, component: str, index: str) -> list:
        """The times on ``index`` of those rows, in the same order: an int on a sequence timeline, a
        ``timedelta`` on a duration timeline (``sim_time``)."""
        return [at for at, _ in self._on(entity, component, index)]
