"""Deterministic truncation of a run_code result to the model-visible byte cap.

Fields are shrunk in a fixed order (value, interrupted_action, internal_trace, stdout, obs_ids,
images_withheld, error) through fixed levels, so the same result always truncates the same way.
Every cut leaves an explicit ``__cab_truncated_*__`` marker, and the result gets a top-level
``__cab_truncated__`` entry naming the fields that were cut and the original size.
"""
from __future__ import annotations

import json

MARK = "__cab_truncated"  # also in sandbox/guest.py, which cannot import it
_ORDER = ("value", "interrupted_action", "internal_trace", "stdout", "obs_ids", "images_withheld", "error")
_LEVELS = ((256, 4096), (64, 1024), (16, 256), (4, 64), (1, 16), (0, 0))


def json_size(obj) -> int:
    """Bytes of ``obj`` as UTF-8 JSON; a lone surrogate (valid in a Python str, not in UTF-8) counts
    as the bytes it would take, instead of failing."""
    return len(json.dumps(obj, ensure_ascii=False, separators=(",", ":"), default=str)
               .encode("utf-8", "surrogatepass"))


NON_FINITE_KEY = "non_finite_as_null"  # where a strict JSON writer notes the numbers it wrote as null
_NOTE_PATHS = 20


def finite_json(obj, path: str = "", found: list | None = None, depth: int = 0):
    """``obj`` with every NaN or infinity (Python or numpy floats, in arrays too) replaced by None,
    so that strict JSON can hold it; the JSON paths of the replaced numbers are appended to ``found``.
    Anything else is left as it is (a writer's ``default`` still converts it)."""
    import math

    import numpy as np

    if found is None:
        found = []
    if isinstance(obj, np.ndarray):
        obj = obj.tolist()
    elif isinstance(obj, np.floating):
        obj = float(obj)
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        found.append(path or "$")
        return None
    if depth > 200:  # deeper than any record; a circular structure stays as it is (the writer says so)
        return obj
    if isinstance(obj, dict):
        return {k: finite_json(v, f"{path}.{k}" if path else str(k), found, depth + 1) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_json(v, f"{path}[{i}]", found, depth + 1) for i, v in enumerate(obj)]
    return obj


def non_finite_note(found: list[str], earlier=None) -> list[str]:
    """The note a strict writer adds beside the data: where numbers became null (the first 20)."""
    paths = (list(earlier) if isinstance(earlier, list) else []) + found
    if len(paths) > _NOTE_PATHS:
        paths = paths[:_NOTE_PATHS] + [f"... and {len(paths) - _NOTE_PATHS} more"]
    return paths


def strict_payload(payload: dict) -> dict:
    """``payload`` itself when strict JSON can hold it; else a copy with null for each NaN or
    infinity and ``non_finite_as_null`` saying where (a tool result the agent sees)."""
    try:
        json.dumps(payload, allow_nan=False, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))
        return payload
    except ValueError:
        found: list[str] = []
        clean = finite_json(payload, "", found)
        if found and isinstance(clean, dict):
            clean[NON_FINITE_KEY] = non_finite_note(found, clean.get(NON_FINITE_KEY))
        return clean


def cut_str(s: str, n: int) -> str:
    if len(s) <= n:
        return s
    return s[:n] + f"...[{MARK}_chars__: {len(s) - n}]"


def shrink(obj, items: int, chars: int):
    """``obj`` with strings cut to ``chars`` and lists/dicts to ``items`` entries, recursively."""
    if isinstance(obj, str):
        return cut_str(obj, chars)
    if isinstance(obj, list):
        out = [shrink(v, items, chars) for v in obj[:items]]
        if len(obj) > items:
            out.append({f"{MARK}_items__": len(obj) - items})
        return out
    if isinstance(obj, dict):
        keys = list(obj)
        kept = {str(k): shrink(obj[k], items, chars) for k in keys[:items]}
        if len(keys) > items:
            kept[f"{MARK}_keys__"] = len(keys) - items
        return kept
    return obj


def _shrink_trace(trace: list, items: int) -> list:
    """Keep the first and last ``items`` entries: how the program started and where it stopped."""
    if len(trace) <= 2 * items:
        return trace
    return trace[:items] + [{f"{MARK}_entries__": len(trace) - 2 * items}] + (trace[-items:] if items else [])


def cap_result(result: dict, cap: int) -> dict:
    """Return ``result`` unchanged if its JSON fits in ``cap`` bytes, else a truncated copy."""
    original = json_size(result)
    if original <= cap:
        return result
    out = dict(result)
    fields: list[str] = []
    marker = {"original_bytes": original, "cap_bytes": cap, "fields": fields}
    out[f"{MARK}__"] = marker
    for name in _ORDER:
        if name not in out or json_size(out) <= cap:
            continue
        for items, chars in _LEVELS:
            if name == "internal_trace":
                out[name] = _shrink_trace(result[name], items * 2)
            elif name in ("stdout", "error") and isinstance(result[name], str):
                out[name] = cut_str(result[name], chars * 8)
            else:
                out[name] = shrink(result[name], items, chars)
            if json_size(out) <= cap:
                break
        if out[name] != result[name]:
            fields.append(name)
    return out
