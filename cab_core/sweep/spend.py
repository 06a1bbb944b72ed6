"""What a sweep has spent on its models so far: USD, tokens and seconds waited on the shared rate
limits, over every attempt folder of the sweep, finished or in flight, set aside or not (money
spent on an attempt that is run again is spent all the same).

A finished attempt's spend is its ``result.json``'s ``agent.usage`` where the harness wrote one,
else its ``model_usage_total`` event; an attempt in flight has neither yet, and its spend is the
sum of its ``model_turn`` events so far (each carries the turn's cost and usage). The progress
lines show it, and ``sweep.max_cost_usd`` is checked against it before each attempt starts
(:func:`cab_core.sweep.manifest.run_job`). Files are read again only when they changed."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Spend:
    """USD (the priced part), tokens (input, cache reads and writes, output) and seconds waited on
    limits; ``attempts``: the attempt folders that spent anything."""
    usd: float = 0.0
    tokens: int = 0
    waited_on_limits_s: float = 0.0
    attempts: int = 0

    def add(self, other: Spend) -> None:
        self.usd += other.usd
        self.tokens += other.tokens
        self.waited_on_limits_s += other.waited_on_limits_s
        self.attempts += other.attempts

    def words(self) -> str:
        """``$1.23 spent, 1.2M tokens, 35 s waiting on limits``."""
        return (f"${self.usd:.2f} spent, {_tokens(self.tokens)} tokens"
                + (f", {self.waited_on_limits_s:.0f} s waiting on limits" if self.waited_on_limits_s >= 0.5 else ""))


def _tokens(n: int) -> str:
    for unit, size in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if n >= size:
            return f"{n / size:.1f}{unit}"
    return str(n)


def _usage_tokens(u: dict) -> int:
    return int(sum(int(u.get(k) or 0) for k in ("input_tokens", "cache_read_tokens", "cache_write_tokens",
                                                 "output_tokens")))


def _from_events(path: Path) -> Spend:
    turns = Spend()
    total: dict | None = None
    try:
        with open(path, encoding="utf-8") as f:
            for line in f:
                if '"model_turn"' not in line and '"model_usage_total"' not in line:
                    continue  # most lines are calls: not parsed
                try:
                    e = json.loads(line)
                except ValueError:  # the line being written
                    continue
                if e.get("kind") == "model_turn":
                    turns.usd += float((e.get("cost") or {}).get("usd") or 0.0)
                    turns.tokens += _usage_tokens(e.get("usage") or {})
                    turns.waited_on_limits_s += float(e.get("waited_on_limits_s") or 0.0)
                elif e.get("kind") == "model_usage_total":
                    total = e
    except OSError:
        return Spend()
    if total is not None:
        turns = Spend(float(total.get("usd") or 0.0), _usage_tokens(total),
                      float(total.get("waited_on_limits_s") or 0.0))
    turns.attempts = int(turns.usd > 0 or turns.tokens > 0)
    return turns


def attempt_spend(folder: Path) -> Spend:
    """One attempt folder's spend (see the module)."""
    try:
        result = json.loads((folder / "result.json").read_text())
    except (OSError, ValueError):
        result = None
    usage = ((result or {}).get("agent") or {}).get("usage") if isinstance(result, dict) else None
    if isinstance(usage, dict):
        s = Spend(float(usage.get("usd") or 0.0), _usage_tokens(usage), float(usage.get("waited_on_limits_s") or 0.0))
        s.attempts = int(s.usd > 0 or s.tokens > 0)
        return s
    return _from_events(folder / "events.jsonl")


_CACHE: dict[Path, tuple[tuple, Spend]] = {}


def _stamp(folder: Path) -> tuple:
    out: list[tuple[int, int] | None] = []
    for name in ("result.json", "events.jsonl"):
        try:
            st = (folder / name).stat()
            out.append((st.st_mtime_ns, st.st_size))
        except OSError:
            out.append(None)
    return tuple(out)


def sweep_spend(sweep_dir: Path) -> Spend:
    """The sweep's spend so far (every folder below ``sweep_dir`` with an ``events.jsonl``)."""
    total = Spend()
    for events in Path(sweep_dir).rglob("events.jsonl"):
        folder = events.parent
        stamp = _stamp(folder)
        hit = _CACHE.get(folder)
        if hit is None or hit[0] != stamp:
            hit = (stamp, attempt_spend(folder))
            _CACHE[folder] = hit
        total.add(hit[1])
    return total
