"""Success beyond the fixed instances: per configuration, on each task's catalog instance beside
its held-out instances (the seeds of the task's ``heldout`` set, ``Task.seed_sets``) and any other
seed; and per appearance randomisation option (``randomize=``). Each cell is successes/attempts with
its Wilson 95 % interval. Pure functions over the report's attempt rows; the seed sets come from
the installed tasks (a task no longer installed: its seeds count as "other")."""
from __future__ import annotations

from cab_core.analysis.measures import wilson
from cab_core.plugins import all_tasks

KINDS = ("catalog", "heldout", "other")
KIND_LABELS = {"catalog": "Catalog instance", "heldout": "Held-out instances", "other": "Other seeds"}


def seed_kinds(tasks: set[str]) -> dict[str, dict[int, str]]:
    """For each installed task of ``tasks``: seed -> "catalog" or "heldout"."""
    installed = all_tasks()
    out: dict[str, dict[int, str]] = {}
    for t in tasks:
        if t not in installed:
            continue
        task = installed[t]
        kinds = {int(s): "heldout" for s in (task.seed_sets or {}).get("heldout", ())}
        kinds[int(task.info.seed)] = "catalog"
        out[t] = kinds
    return out


def cell(rows: list[dict]) -> dict | None:
    if not rows:
        return None
    k, n = sum(1 for r in rows if r["success"]), len(rows)
    lo, hi = wilson(k, n)
    return {"successes": k, "attempts": n, "rate": k / n, "wilson95": [lo, hi]}


def by_instance_kind(rows: list[dict], kinds: dict[str, dict[int, str]]) -> dict | None:
    """``{config: {kind: cell}}``; None when every attempt is on a catalog instance (nothing to
    set beside it)."""
    kind = lambda r: kinds.get(r["task"], {}).get(r.get("seed"), "other")  # noqa: E731
    if all(kind(r) == "catalog" for r in rows):
        return None
    out: dict[str, dict] = {}
    for r in rows:
        out.setdefault(r["config"], {k: [] for k in KINDS})[kind(r)].append(r)
    return {c: {k: cell(v) for k, v in by.items()} for c, by in out.items()}


def by_randomization(rows: list[dict]) -> dict | None:
    """``{"options": [...], "configs": {config: {option: cell}}}``; None when no attempt was
    randomised."""
    options = sorted({r.get("randomize") or "none" for r in rows}, key=lambda o: (o != "none", o))
    if options == ["none"]:
        return None
    out: dict[str, dict] = {}
    for r in rows:
        out.setdefault(r["config"], {o: [] for o in options})[r.get("randomize") or "none"].append(r)
    return {"options": options, "configs": {c: {o: cell(v) for o, v in by.items()} for c, by in out.items()}}


def _show(c: dict | None) -> str:
    if c is None:
        return "–"
    lo, hi = c["wilson95"]
    return f"{c['successes']}/{c['attempts']} ({100 * c['rate']:.0f}%, {100 * lo:.0f}–{100 * hi:.0f}%)"


def tables(r: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """The report's tables for ``r["instances"]`` and ``r["randomization"]`` (where present)."""
    out = []
    order = {c["config"]: i for i, c in enumerate(r.get("configs") or [])}
    ranked = lambda d: sorted(d.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0]))  # noqa: E731
    inst = r.get("instances")
    if inst:
        out.append(("Success by task instance: the catalog's fixed instance beside held-out and other seeds "
                    "(successes/attempts, rate, Wilson 95% interval)",
                    ["Configuration", *[KIND_LABELS[k] for k in KINDS]],
                    [[c, *[_show(cells[k]) for k in KINDS]] for c, cells in ranked(inst)]))
    rnd = r.get("randomization")
    if rnd:
        out.append(("Success by appearance randomisation (randomize=; successes/attempts, rate, Wilson 95% interval)",
                    ["Configuration", *rnd["options"]],
                    [[c, *[_show(cells[o]) for o in rnd["options"]]] for c, cells in ranked(rnd["configs"])]))
    return out
