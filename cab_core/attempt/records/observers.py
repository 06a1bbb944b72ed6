"""Record observers: plugins that follow an attempt's record as it is written (hook
:func:`cab_core.contracts.hookspecs.cab_record_observers`).

Which observers an attempt gets is the config key ``record.observers``:

* absent or null: every installed observer, each with an empty config, except those whose factory
  has the attribute ``on_by_default = False`` (an observer that costs an attempt more than it
  should pay by default: named, it is selected like any other);
* a list of names: those (``[]``: none), each with an empty config;
* a mapping ``name -> config`` (a mapping, or null for an empty one): those, each with its config.

A name no installed plugin registers is a :class:`~cab_core.errors.ConfigError` naming the
installed ones, raised by :func:`select` before any simulator starts.

An observer is created once the attempt's folder exists, before its first event, with
``factory({**its config, "name": name, "attempt_dir": "<the attempt's folder>"})``; it may write
files of its own there (the record's own files are the recorder's). It then receives, through
``on_event(event)``, every event of the attempt after the recorder has written it, and through
``on_result(result)`` the final result after ``result.json`` is written: each a read-only deep copy
(mappings are :class:`ReadOnlyDict`, lists tuples), so it can neither change the attempt nor what
another observer sees. Both methods are optional.

An observer that raises (its factory included) is logged once and detached; the attempt goes on,
its record gains an ``observer_detached`` event (while its events are still being written), and its
verdict is unaffected.
"""
from __future__ import annotations

import json
import logging
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.plugins import ObserverSpec

log = logging.getLogger("cab")


class ReadOnlyDict(dict):
    """A dict that refuses every change (``TypeError``). JSON-serialisable as it is; ``copy`` and
    ``deepcopy`` give plain, mutable dicts."""

    def _refuse(self, *args, **kwargs):
        raise TypeError("a recorded event is read-only")

    __setitem__ = __delitem__ = __ior__ = _refuse
    clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):
        return dict, (dict(self),)


def freeze(obj: Any) -> Any:
    """A read-only deep copy of JSON data: mappings become :class:`ReadOnlyDict`, lists tuples."""
    if isinstance(obj, dict):
        return ReadOnlyDict((k, freeze(v)) for k, v in obj.items())
    if isinstance(obj, (list, tuple)):
        return tuple(freeze(v) for v in obj)
    return obj


class Observers:
    """The observers attached to one attempt's recorder. A fault of one is logged once and it is
    detached; :meth:`create` and :meth:`dispatch` return ``(name, stage, error)`` of each fault so
    that the recorder can write it to the record."""

    def __init__(self) -> None:
        self._attached: list[tuple[str, Any]] = []

    @property
    def names(self) -> list[str]:
        return [n for n, _ in self._attached]

    def _fault(self, name: str, stage: str, e: Exception) -> tuple[str, str, str]:
        error = f"{type(e).__name__}: {e}"
        log.warning("record observer %r failed in %s (%s); detached, the attempt goes on", name, stage, error)
        return name, stage, error

    def create(self, specs: list[ObserverSpec], attempt_dir: str) -> list[tuple[str, str, str]]:
        faults = []
        for spec in specs:
            try:
                obj = spec.factory({**spec.cfg, "name": spec.name, "attempt_dir": attempt_dir})
            except Exception as e:
                faults.append(self._fault(spec.name, "factory", e))
                continue
            self._attached.append((spec.name, obj))
        return faults

    def dispatch(self, method: str, text: str) -> list[tuple[str, str, str]]:
        """Give each attached observer its own frozen copy of the JSON ``text`` (an event or the
        result, as written) through ``method``."""
        faults = []
        for name, obj in list(self._attached):
            fn = getattr(obj, method, None)
            if fn is None:
                continue
            try:
                fn(freeze(json.loads(text)))
            except Exception as e:
                self._attached = [(n, o) for n, o in self._attached if o is not obj]
                faults.append(self._fault(name, method, e))
        return faults
