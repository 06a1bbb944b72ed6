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
        out = {str(k): shrink(obj[k], items, chars) for k in keys[:items]}
        if len(keys) > items:
            out[f"{MARK}_keys__"] = len(keys) - items
        return out
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
    marker = {"original_bytes": original, "cap_bytes": cap, "fields": []}
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
            marker["fields"].append(name)
    return out
