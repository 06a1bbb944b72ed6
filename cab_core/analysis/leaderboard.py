"""Leaderboard rows: one JSON row per configuration of a sweep, with its provenance
(``cab-export leaderboard``, docs/export.md).

A row carries the counts cab-report computes (:func:`cab_core.analysis.report.build`: attempts,
successes, the Wilson 95 % interval, tasks and tasks covered), where they came from (cab version,
the configuration's comparison contract: its attempts' contracts combined as the sweep manifest
combines them, :func:`cab_core.analysis.contract.combined`; simulator, embodiment, planner, seeds) and,
where the configuration reproduces one of a paper's (a task suite's published figures, hook
``cab_published_figures``), the paper's name for it (``name_in_paper``), the table its success
figure was reported in (``reported_table``) and the paper's counts. The rows are written as JSON
Lines (one object a line) and read back with :func:`read`, which checks every count. The data comes
from :func:`cab_core.analysis.summary.sweep_data`, as the sweep exporters' does."""
from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from cab_core.analysis import summary
from cab_core.analysis.measures import wilson
from cab_core.errors import RecordError

FORMAT = "cab-leaderboard/1"
FILE = "leaderboard.jsonl"

#: (key, type, meaning): the keys of a row, in order (docs/export.md lists them)
COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("format", "string", f"the row format, '{FORMAT}'"),
    ("config", "string", "the configuration as cab-report names it: 'model (harness, sim)'"),
    ("model", "string", "result.json model"),
    ("harness", "string", "result.json harness"),
    ("simulator", "string", "result.json sim"),
    ("embodiment", "string", "result.json embodiment (null: several)"),
    ("planner", "string", "result.json planner (null: several)"),
    ("attempts", "int", "finished, scored attempts"),
    ("successes", "int", "attempts the hidden verifier scored a success"),
    ("success_rate", "float", "successes / attempts"),
    ("wilson95", "[float, float]", "the Wilson 95 % interval of the success rate (as cab-report)"),
    ("tasks", "int", "tasks attempted"),
    ("tasks_covered", "int", "tasks with at least one success (task coverage)"),
    ("seeds", "[int]", "the task seeds played, sorted"),
    ("cab_version", "string", "versions.cab of the attempts (null: none recorded or several: see cab_versions)"),
    ("cab_versions", "[string]", "every versions.cab among the attempts, sorted"),
    ("contract_digest", "string", "the configuration's comparison contract: its attempts' result.json contracts "
                                  "combined (as sweep.json's contracts; null: an attempt has none)"),
    ("contract_parts", "{string: string}", "that contract's parts by name ({}: none), for telling what two rows differ in"),
    ("sweep_fingerprint", "string", "the sweep manifest's fingerprint (sweep.json; null: no manifest)"),
    ("name_in_paper", "string", "the paper's name of the configuration this one reproduces (null: none)"),
    ("reported_table", "string", "the paper's table its success and coverage come from (null: none)"),
    ("paper_successes", "int", "the paper's successes for it (null: none)"),
    ("paper_attempts", "int", "the paper's attempts for it"),
    ("paper_tasks_covered", "int", "the paper's tasks covered"),
    ("paper_tasks", "int", "the paper's tasks"),
    ("exported", "string", "when the row was written (UTC, ISO 8601)"),
)
KEYS = tuple(k for k, _, _ in COLUMNS)
COUNTS = ("attempts", "successes", "tasks", "tasks_covered")


def _one(values: set) -> Any:
    return next(iter(values)) if len(values) == 1 else None


def rows(root: Path, r: Mapping[str, Any], figures: Mapping[str, Any] | None = None,
         labels: Mapping[str, str] | None = None, now: float | None = None) -> list[dict]:
    """One row per configuration of the sweep below ``root`` (:data:`COLUMNS`), in cab-report's order:
    ``r`` is cab-report's build of it (:func:`cab_core.analysis.report.build`), read with the records
    by :func:`cab_core.analysis.summary.sweep_data`. ``figures``: published figures
    (:func:`~cab_core.analysis.summary.published`) whose configurations give ``name_in_paper``: the one
    of the same model and harness, or the one ``labels`` names (``{configuration: paper name}``)."""
    data = summary.sweep_data(Path(root), r, figures, labels)
    fingerprint = (data["sweep"] or {}).get("fingerprint")
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(time.time() if now is None else now))
    out = []
    for c in data["configs"]:
        res = [a["result"] for a in c["records"]]

        def seen(key: str, rs: list[dict] = res) -> set:
            return {r.get(key) for r in rs if r.get(key) is not None}

        cab = sorted({str(v) for v in ((r.get("versions") or {}).get("cab") for r in res) if v is not None})
        paper, whole = c["paper"] or {}, c["contract"]
        counts = paper.get("counts") or {}
        out.append({
            "format": FORMAT, "config": c["config"], "model": _one(seen("model")), "harness": _one(seen("harness")),
            "simulator": _one(seen("sim")), "embodiment": _one(seen("embodiment")), "planner": _one(seen("planner")),
            "attempts": c["attempts"], "successes": c["successes"], "success_rate": c["success_rate"],
            "wilson95": c["wilson95"], "tasks": c["tasks"], "tasks_covered": c["coverage"],
            "seeds": sorted(seen("seed")), "cab_version": _one(set(cab)), "cab_versions": cab,
            "contract_digest": whole["digest"] if whole else None, "contract_parts": whole["parts"] if whole else {},
            "sweep_fingerprint": fingerprint,
            "name_in_paper": paper.get("name"), "reported_table": counts.get("table"),
            "paper_successes": counts.get("successes"), "paper_attempts": counts.get("attempts"),
            "paper_tasks_covered": counts.get("tasks_covered"), "paper_tasks": counts.get("tasks"),
            "exported": stamp,
        })
    return out


def write(rs: list[dict], path: Path) -> Path:
    """The rows as JSON Lines at ``path`` (written whole, then moved into place)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text("".join(json.dumps(row, sort_keys=False) + "\n" for row in rs))
    os.replace(tmp, path)
    return path


def _check_row(row: Any, where: str) -> dict:
    if not isinstance(row, dict):
        raise RecordError(f"{where}: a row is a JSON object, got {type(row).__name__}")
    missing = [k for k in KEYS if k not in row]
    if missing:
        raise RecordError(f"{where}: missing {', '.join(missing)}")
    if row["format"] != FORMAT:
        raise RecordError(f"{where}: format {row['format']!r}, expected {FORMAT!r}")
    for k in COUNTS:
        if not isinstance(row[k], int) or isinstance(row[k], bool) or row[k] < 0:
            raise RecordError(f"{where}: {k} should be a count, got {row[k]!r}")
    if row["successes"] > row["attempts"] or row["tasks_covered"] > row["tasks"]:
        raise RecordError(f"{where}: successes {row['successes']}/{row['attempts']}, "
                          f"tasks covered {row['tasks_covered']}/{row['tasks']}: more than possible")
    lo, hi = wilson(row["successes"], row["attempts"])
    w = row["wilson95"]
    if not (isinstance(w, list) and len(w) == 2 and abs(w[0] - lo) < 1e-9 and abs(w[1] - hi) < 1e-9):
        raise RecordError(f"{where}: wilson95 {w!r} is not the interval of {row['successes']}/{row['attempts']} "
                          f"({lo:.6f}, {hi:.6f})")
    return row


def read(path: Path) -> list[dict]:
    """The rows of a leaderboard file written by :func:`write`, each checked: every key present, the
    counts non-negative integers that fit together, the interval the one its counts give. A bad
    row is one :class:`~cab_core.errors.RecordError` line naming it."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except OSError as e:
        raise RecordError(f"{path}: cannot read ({e.strerror or e})") from e
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
        except json.JSONDecodeError as e:
            raise RecordError(f"{path}:{i}: not JSON ({e.msg})") from e
        out.append(_check_row(row, f"{path}:{i}"))
    return out
