"""Compares the records of two sweeps attempt by attempt, ignoring the fields that measure wall-clock time.

    python scripts/compare_oracle_records.py A B [--ignore PATH ...] [--no-images]

A and B are sweep folders (``cab -m ... hydra.sweep.dir=A``). Every attempt folder under each (a folder
holding ``result.json``, at any depth, outside ``set_aside/``) is keyed by its result's task, model,
simulator, seed and attempt number, and the attempts of A and B with the same key are compared. When A and
B are themselves attempt folders (each holds ``result.json``), those two are compared, whatever their keys.
What is compared:

- ``events.jsonl``, event by event (parsed JSON, so key order and number spelling do not matter);
- ``result.json``: its verdict first, then every other section (termination, claim, budget, counts,
  checkpoints, versions, video, ...); the ``infrastructure`` section is left out: a try that crashed and
  was retried leaves its wall-clock times there, and the try that counts is compared like any other;
- ``privileged/snapshots.jsonl`` and ``privileged/scene_info.json``: the verifier's view of the world after
  each call;
- ``observations/*.png``, byte for byte (``--no-images`` skips them).

Values are compared exactly: the same JSON type and the same value (a float is not equal to an int of the
same value; NaN equals NaN), except the lists in ``UNORDERED_FIELDS``, compared as sets. The fields listed in
``TIMING_FIELDS`` (and those given with ``--ignore``) are dropped before comparing: each measures wall-clock
time (seconds), and they are the fields whose values changed between two sweeps of the same code. The video
(``video.mp4``) is not compared: its frame count and size are in ``result.json``.

One line per attempt, sorted by key: ``identical`` or ``DIFFERS``, with the file, the first differing event
(its ``seq``, kind and tool) and the path of the first differing field with both values; then ``only in A``
or ``only in B`` for an attempt without a partner, and a summary line. Exit status: 0 when every attempt is
paired and identical, 1 otherwise, 2 when a folder holds no attempt or two attempts with the same key.

Checking that a change keeps behaviour (issue 27: oracle records identical at the catalog seeds on the three
simulators): run the same sweep with the code before and after the change, one attempt at a time, and compare.

    T=beat_block_hammer,blocks_ranking_size,click_bell,dump_bin_bigbin,grab_roller_dual_contact,handover_block
    T=$T,handover_mic,hanging_mug,lift_pot,move_can_pot,open_laptop_setup_arm,open_microwave,pick_diverse_bottles
    T=$T,place_bread_basket,place_bread_skillet,place_cans_plasticbox,place_dual_shoes,place_mouse_pad
    T=$T,place_object_basket,press_stapler,put_bottles_dustbin,rotate_qrcode,scan_object,stack_blocks_three
    T=$T,stack_bowls_three
    cab -m task=$T model=oracle sim=sapien,pybullet,mujoco hydra.sweep.dir=/tmp/oracle_after hydra.launcher.n_jobs=1
    python scripts/compare_oracle_records.py /tmp/oracle_before /tmp/oracle_after

``seed`` is left unset: each task runs at its catalog seed. To run an older commit with the same virtual
environment, check it out in a worktree (``git worktree add /tmp/before <commit>``) and put its package roots
first on ``PYTHONPATH``: the worktree itself, each ``plugins/<p>``, and a folder holding a link ``cab_conf`` to
its ``conf/``; run ``cab`` from the worktree (the installed entry points name modules, found on that path).
On a 2-core machine shared with other work, the 75 attempts took 30 min 21 s (2026-11-27), all successes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

# The fields that measure wall-clock time, by file: dotted paths inside each event (each line) or inside the
# whole file, ``*`` standing for any one key or list index. Between two sweeps of the same code (the 25 oracles at
# their catalog seeds on three simulators, 2026-11-27) these fields, and no other, changed in every attempt, except
# wall_seconds_credited (0.0: the oracle calls no provider) and infrastructure (no try failed).
TIMING_FIELDS: dict[str, tuple[str, ...]] = {
    "events.jsonl": (
        "t_wall",                         # seconds since the attempt started when the event was written
        "wall_seconds",                   # a call's wall time
        "setup_seconds",                  # attempt_start: the time the world took to build
    ),
    "result.json": (
        "timing",                         # wall_seconds, setup_seconds
        "budget.wall_seconds_used",       # the wall time charged against the wall budget
        "budget.wall_seconds_credited",   # wall time of provider outages credited back to the wall budget
        "video.render_seconds",           # the time the video took to render
        "infrastructure",                 # see the module docstring
    ),
    "privileged/snapshots.jsonl": (),
    "privileged/scene_info.json": (),
}
# Lists compared as sets (sorted before comparing), by file: the BLAS libraries are listed in the order the
# process happened to load them, which changes from process to process (two sweeps of the same code, and a
# sweep's warm worker and a single run of the same attempt, list them in either order).
UNORDERED_FIELDS: dict[str, tuple[str, ...]] = {
    "result.json": ("versions.numerics.blas",),
}
Key = tuple[str, str, str, str, str]
Pattern = tuple[str, ...]


def find_attempts(root: Path) -> dict[Key, Path]:
    """The attempt folders under ``root`` by (task, model, sim, seed, attempt); exits 2 on a duplicate key."""
    attempts: dict[Key, Path] = {}
    for result_file in sorted(root.rglob("result.json")):
        if "set_aside" in result_file.relative_to(root).parts:
            continue
        result = json.loads(result_file.read_text())
        key = (str(result.get("task")), str(result.get("model")), str(result.get("sim")), str(result.get("seed")),
               str(result.get("attempt")))
        if key in attempts:
            print(f"compare_oracle_records: {root} holds two attempts of {label(key)}: {attempts[key]} and "
                  f"{result_file.parent}", file=sys.stderr)
            sys.exit(2)
        attempts[key] = result_file.parent
    return attempts


def label(key: Key) -> str:
    """The attempt's name as the sweep's folders spell it: task/model/sim/seed-S/attempt-A."""
    task, model, sim, seed, attempt = key
    return f"{task}/{model}/{sim}/seed-{seed}/attempt-{attempt}"


def drop(value: Any, patterns: list[Pattern]) -> Any:
    """``value`` without the fields that ``patterns`` (paths split at dots, ``*`` for any part) point to."""
    if not patterns or not isinstance(value, (dict, list)):
        return value
    items = value.items() if isinstance(value, dict) else enumerate(value)
    kept: dict[Any, Any] = {}
    for k, v in items:
        matching = [p for p in patterns if p[0] in ("*", str(k))]
        if any(len(p) == 1 for p in matching):
            continue
        kept[k] = drop(v, [p[1:] for p in matching])
    return kept if isinstance(value, dict) else list(kept.values())


def sort_lists(value: Any, patterns: list[Pattern]) -> Any:
    """``value`` with the lists that ``patterns`` point to sorted (by their items' JSON)."""
    if not patterns:
        return value
    if isinstance(value, list) and any(not p for p in patterns):
        return sorted(value, key=lambda item: json.dumps(item, sort_keys=True))
    if not isinstance(value, (dict, list)):
        return value
    items = value.items() if isinstance(value, dict) else enumerate(value)
    kept = {k: sort_lists(v, [p[1:] for p in patterns if p and p[0] in ("*", str(k))]) for k, v in items}
    return kept if isinstance(value, dict) else list(kept.values())


def short(value: Any) -> str:
    """``value`` as JSON, cut to 100 characters."""
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= 100 else text[:97] + "..."


def first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """The path of the first field where ``a`` and ``b`` differ, with both values; None when they are equal."""
    where = path or "(the whole value)"
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            sub = f"{path}.{k}" if path else k
            if k not in a:
                return f"{sub}: missing in A, {short(b[k])} in B"
            if k not in b:
                return f"{sub}: {short(a[k])} in A, missing in B"
            found = first_difference(a[k], b[k], sub)
            if found:
                return found
        return None
    if isinstance(a, list) and isinstance(b, list):
        for i, (x, y) in enumerate(zip(a, b)):
            found = first_difference(x, y, f"{path}[{i}]")
            if found:
                return found
        if len(a) != len(b):
            return f"{where}: {len(a)} items in A, {len(b)} in B"
        return None
    if type(a) is not type(b):
        return f"{where}: {short(a)} ({type(a).__name__}) in A, {short(b)} ({type(b).__name__}) in B"
    if isinstance(a, float) and math.isnan(a) and math.isnan(b):
        return None
    if a != b:
        return f"{where}: {short(a)} in A, {short(b)} in B"
    return None


def read_records(folder: Path, name: str) -> list[Any] | None:
    """The JSON values of a record file: one a line for ``.jsonl``, else one; None when the file is missing."""
    path = folder / name
    if not path.exists():
        return None
    if name.endswith(".jsonl"):
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [json.loads(path.read_text())]


def where_in(name: str, index: int, value: Any) -> str:
    """How to name the ``index``-th value of a record file in a message: an event by its seq, kind and tool."""
    if name == "events.jsonl" and isinstance(value, dict) and "seq" in value:
        tool = f" {value['tool']}" if "tool" in value else ""
        return f"{name} event seq {value['seq']} ({value.get('kind')}{tool})"
    if name.endswith(".jsonl"):
        label_ = f" ({value['label']})" if isinstance(value, dict) and "label" in value else ""
        return f"{name} line {index + 1}{label_}"
    return name


def compare_file(a: Path, b: Path, name: str, patterns: list[Pattern], unordered: list[Pattern]) -> str | None:
    """The first difference between the record file ``name`` of two attempts, the fields in ``patterns``
    dropped and the lists in ``unordered`` sorted."""
    values_a, values_b = read_records(a, name), read_records(b, name)
    if values_a is None or values_b is None:
        return None if values_a is values_b else f"{name}: {'missing in A' if values_a is None else 'missing in B'}"
    for i, (x, y) in enumerate(zip(values_a, values_b)):
        x, y = sort_lists(drop(x, patterns), unordered), sort_lists(drop(y, patterns), unordered)
        if name == "result.json":   # the verdict first: it is what a reader of the comparison looks for
            found = first_difference(x.get("verdict"), y.get("verdict"), "verdict") or first_difference(x, y)
        else:
            found = first_difference(x, y)
        if found:
            return f"{where_in(name, i, values_a[i])}: {found}"
    if len(values_a) != len(values_b):
        return f"{name}: {len(values_a)} lines in A, {len(values_b)} in B"
    return None


def compare_images(a: Path, b: Path) -> str | None:
    """The first observation image (``observations/*.png``) that differs by name or by bytes."""
    names_a = sorted(p.name for p in (a / "observations").glob("*.png"))
    names_b = sorted(p.name for p in (b / "observations").glob("*.png"))
    if names_a != names_b:
        return f"observations: {len(names_a)} images in A, {len(names_b)} in B ({short(names_a)} / {short(names_b)})"
    for name in names_a:
        if (a / "observations" / name).read_bytes() != (b / "observations" / name).read_bytes():
            return f"observations/{name}: the images differ"
    return None


def compare_attempt(a: Path, b: Path, extra: list[Pattern], images: bool) -> str | None:
    """The first difference between the records of two attempt folders; None when they are the same."""
    for name, fields in TIMING_FIELDS.items():
        unordered = [tuple(f.split(".")) for f in UNORDERED_FIELDS.get(name, ())]
        found = compare_file(a, b, name, [tuple(f.split(".")) for f in fields] + extra, unordered)
        if found:
            return found
    return compare_images(a, b) if images else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("a", type=Path, help="a sweep folder (e.g. the records of the code before a change)")
    parser.add_argument("b", type=Path, help="another sweep folder (e.g. the same sweep after the change)")
    parser.add_argument("--ignore", action="append", default=[], metavar="PATH",
                        help="also ignore this field (a dotted path, * for any part) in every record file; repeatable")
    parser.add_argument("--no-images", action="store_true", help="do not compare the observation images")
    args = parser.parse_args(argv)
    extra = [tuple(p.split(".")) for p in args.ignore]
    if (args.a / "result.json").exists() and (args.b / "result.json").exists():
        found = compare_attempt(args.a, args.b, extra, not args.no_images)
        print(f"DIFFERS    {args.a} vs {args.b}: {found}" if found else f"identical  {args.a} vs {args.b}")
        return 1 if found else 0
    attempts_a, attempts_b = find_attempts(args.a), find_attempts(args.b)
    for root, attempts in ((args.a, attempts_a), (args.b, attempts_b)):
        if not attempts:
            print(f"compare_oracle_records: no attempt (result.json) under {root}", file=sys.stderr)
            return 2
    counts = {"identical": 0, "differ": 0, "only in A": 0, "only in B": 0}
    for key in sorted(set(attempts_a) | set(attempts_b)):
        if key not in attempts_b:
            counts["only in A"] += 1
            print(f"only in A  {label(key)}")
        elif key not in attempts_a:
            counts["only in B"] += 1
            print(f"only in B  {label(key)}")
        else:
            found = compare_attempt(attempts_a[key], attempts_b[key], extra, not args.no_images)
            counts["differ" if found else "identical"] += 1
            print(f"DIFFERS    {label(key)}: {found}" if found else f"identical  {label(key)}")
    print(f"{sum(counts.values())} attempts: " + ", ".join(f"{n} {what}" for what, n in counts.items()))
    return 0 if counts["identical"] == sum(counts.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
