"""The comparison contract's form: its parts (:data:`PARTS`), how a part is digested
(:func:`digest`) and how contracts combine (:func:`combined`). What each part covers is computed
from an attempt's spec by :mod:`cab_core.attempt.engine.contract` (every ``result.json`` holds it
under ``contract``); reports read and compare contracts with :mod:`cab_core.analysis.contract` (the
public API, which re-exports what is here); docs/comparing.md.

Each part is the SHA-256 (hex) of its canonical JSON: sorted keys, no whitespace, ASCII, a float
that is an integer written as one (``60.0`` and ``60`` are the same budget), numpy scalars as the
numbers they hold; so the digest is the same on every machine, under every Python from 3.11 and
every numpy.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from typing import Any

from cab_core.errors import RecordError

#: the parts of a contract, in the order a difference is named
PARTS = ("tools", "task", "seeds", "budget", "embodiment", "planner", "simulator", "variation", "harness",
         "sandbox", "serving")

#: configuration keys that do not change what an attempt measures: launcher figures, caches, how a
#: harness is reached and how long it waits for a client that went away
NOT_MEASURED = frozenset({"slot_memory_mb", "brdf_cache", "transport", "host", "port", "auth", "idle_timeout_s",
                          "linger_s", "startup_timeout_s"})

# -- digests --------------------------------------------------------------------------------------
def _canonical(value: Any) -> Any:
    """``value`` as plain JSON data: mappings with string keys, lists, numbers (a float that is an
    integer written as one: ``60.0`` and ``60`` are the same budget), strings, booleans, null."""
    if hasattr(value, "item") and callable(value.item) and not isinstance(value, (str, bytes)):
        try:
            value = value.item()  # a numpy scalar
        except (TypeError, ValueError):
            pass
    if isinstance(value, Mapping):
        return {str(k): _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        if value != value or value in (float("inf"), float("-inf")):
            raise RecordError(f"a contract holds no non-finite number, got {value!r}")
        return int(value) if value.is_integer() else value
    if hasattr(value, "tolist"):
        return _canonical(value.tolist())
    return str(value)


def canonical_json(value: Any) -> str:
    """The one text of ``value`` that is digested: sorted keys, no whitespace, ASCII."""
    return json.dumps(_canonical(value), sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def digest(value: Any) -> str:
    """SHA-256 (hex) of :func:`canonical_json` of ``value``."""
    return hashlib.sha256(canonical_json(value).encode("ascii")).hexdigest()


def whole(parts: Mapping[str, str]) -> dict:
    """``{"digest", "parts"}``: the parts by name, and the digest over them."""
    return {"digest": digest(dict(parts)), "parts": dict(sorted(parts.items()))}


def combined(contracts: Iterable[Mapping]) -> dict:
    """One contract over several (a configuration's attempts): each part the digest of the sorted
    set of that part's digests among them (a part some lack counts ``null`` there)."""
    cs = [c["parts"] for c in contracts]
    names = sorted({p for c in cs for p in c})
    return whole({p: digest(sorted({c.get(p) or "" for c in cs})) for p in names})
