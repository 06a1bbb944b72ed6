"""Token usage and its API-equivalent cost, shared by every harness that drives a priced model:
the cost of a request from the model config's ``pricing`` block (USD per million tokens)::

    pricing: {input_per_mtok: 5.0, output_per_mtok: 25.0, cache_read_per_mtok: 0.5, cache_write_per_mtok: 6.25}

Usage convention (every provider adapter maps to it): ``input_tokens`` are the *uncached* input
tokens; ``cache_read_tokens`` and ``cache_write_tokens`` are counted separately; ``output_tokens``
include reasoning tokens (``reasoning_tokens`` is the part of them spent reasoning, for
reporting only). Missing rates cost 0; a cache rate left out falls back to the input rate."""
from __future__ import annotations

from dataclasses import asdict, dataclass

from cab_core.errors import ConfigError


@dataclass
class Usage:
    """Tokens of one request (or a total), in the convention above."""
    input_tokens: int = 0
    output_tokens: int = 0
    reasoning_tokens: int = 0
    cache_read_tokens: int = 0
    cache_write_tokens: int = 0


_KEYS = ("input_per_mtok", "output_per_mtok", "cache_read_per_mtok", "cache_write_per_mtok")


def rates(pricing: dict | None) -> dict[str, float] | None:
    if not pricing:
        return None
    unknown = set(pricing) - set(_KEYS) - {"currency", "source"}
    if unknown:
        raise ConfigError(f"model.pricing: unknown keys {sorted(unknown)}; expected {list(_KEYS)}")
    try:
        r = {k: float(pricing[k]) for k in _KEYS if pricing.get(k) is not None}
    except (TypeError, ValueError) as e:
        raise ConfigError(f"model.pricing: rates must be numbers ({e})") from None
    if any(v < 0 for v in r.values()):
        raise ConfigError("model.pricing: rates must not be negative")
    r.setdefault("input_per_mtok", 0.0)
    r.setdefault("output_per_mtok", 0.0)
    r.setdefault("cache_read_per_mtok", r["input_per_mtok"])
    r.setdefault("cache_write_per_mtok", r["input_per_mtok"])
    return r


def cost(usage: Usage, pricing: dict | None) -> dict:
    """``{"usd": total or None, "input": .., "output": .., "cache_read": .., "cache_write": ..}``."""
    r = rates(pricing)
    if r is None:
        return {"usd": None}
    parts = {
        "input": usage.input_tokens * r["input_per_mtok"] / 1e6,
        "output": usage.output_tokens * r["output_per_mtok"] / 1e6,
        "cache_read": usage.cache_read_tokens * r["cache_read_per_mtok"] / 1e6,
        "cache_write": usage.cache_write_tokens * r["cache_write_per_mtok"] / 1e6,
    }
    out = {k: round(v, 8) for k, v in parts.items()}
    out["usd"] = round(sum(parts.values()), 8)
    return out


def usage_dict(u: Usage) -> dict:
    return asdict(u)
