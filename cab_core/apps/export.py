"""``cab-export``: records written elsewhere, for other tools.

    cab-export parquet <sweep dir> [--out DIR]        attempts.parquet and calls.parquet (the sweep as a dataset)
    cab-export leaderboard <sweep dir> [--out DIR]    leaderboard.jsonl: one row per configuration, with provenance
    cab-export <format> <attempt or sweep dir> [--out DIR]   one export per attempt, by an exporter plugin

``parquet`` is the core's own: one row per finished attempt (:data:`ATTEMPT_COLUMNS`) and one per
call event (:data:`CALL_COLUMNS`), written with pyarrow (the ``export`` extra). Every other format
is an exporter plugin's (hook ``cab_record_exporters``, :func:`cab_core.plugins.registry`): it gets
each finished attempt's folder and writes into it (or below ``--out``, the attempt's path relative
to the given folder kept). A sweep exporter plugin (hook ``cab_sweep_exporters``) gets the whole
folder once. ``leaderboard`` is the core's too (:mod:`cab_core.analysis.leaderboard`). The columns and
each exporter's output are described in ``docs/export.md``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cab_core.analysis import leaderboard, report, summary
from cab_core.analysis.against import parse_labels
from cab_core.analysis.attempts import scan
from cab_core.analysis.measures import AttemptMeasures
from cab_core.errors import CabError, ConfigError, MissingDependency
from cab_core.plugins import registry

PARQUET = "parquet"
LEADERBOARD = "leaderboard"
ATTEMPTS_FILE = "attempts.parquet"
CALLS_FILE = "calls.parquet"
ERROR_TEXT_LIMIT = 500  # characters of a call's error message kept

# (column, type, meaning): the schema of attempts.parquet, in column order (docs/export.md lists them)
ATTEMPT_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("attempt_key", "string", "the attempt's folder relative to the exported folder ('/' separated); the key of calls.parquet"),
    ("config", "string", "the configuration as cab-report names it: 'model (harness, sim)'"),
    ("model", "string", "result.json model"),
    ("harness", "string", "result.json harness"),
    ("sim", "string", "result.json sim: the simulator"),
    ("embodiment", "string", "result.json embodiment"),
    ("planner", "string", "result.json planner"),
    ("task", "string", "result.json task"),
    ("seed", "int64", "the task instance's seed"),
    ("attempt", "int64", "the attempt number"),
    ("agent_clients", "string", "the MCP clients that played it, 'name/version' joined by ', ' (null for other harnesses)"),
    ("serving_engine", "string", "the engine that served the model (vllm, llama.cpp, ollama; null: unknown or not probed)"),
    ("serving_version", "string", "that engine's version, where the server says"),
    ("salvaged_calls", "int64", "tool calls the harness salvaged from the server's output (server-side, not the model's)"),
    ("perturbation_seed", "int64", "perturb.seed (null: not perturbed)"),
    ("perturbation_position_m", "float64", "perturb.position_m: the largest shift an object could get, metres"),
    ("perturbation_angle_deg", "float64", "perturb.angle_deg: the largest turn an object could get, degrees"),
    ("perturbation_physics_fraction", "float64", "perturb.physics_fraction: the largest relative change of a physical parameter"),
    ("fork_parent", "string", "a fork's parent attempt, relative to this attempt's folder (null: not a fork)"),
    ("fork_at", "int64", "the parent's charged call after which the fork started"),
    ("fork_exact", "bool", "whether the re-executed prefix matched the parent's exactly"),
    ("fork_max_tcp_error_m", "float64", "largest TCP deviation of the re-executed prefix, metres"),
    ("success", "bool", "verdict.success: the hidden verifier's verdict"),
    ("scoring", "string", "verdict.scoring: final state or latched event"),
    ("margin_predicate", "string", "verdict.margin.predicate: the predicate that decided the verdict"),
    ("margin_fraction", "float64", "verdict.margin.fraction: by how much, as a fraction of its tolerance"),
    ("borderline", "bool", "verdict.margin.borderline: decided by less than 10 % of a tolerance"),
    ("success_claim", "bool", "claim.success_claim: what the agent said at done (null: no claim)"),
    ("claim", "string", "the claim against the verdict: correct, over, under, absent (as cab-report)"),
    ("claim_report", "string", "claim.report: the agent's report at done"),
    ("termination_reason", "string", "termination.reason: done, tool_budget, sim_budget, no_done, ..."),
    ("termination_detail", "string", "termination.detail"),
    ("stopping", "string", "the stopping condition: done, tool, phys, other (as cab-report)"),
    ("tool_calls_used", "int64", "budget.tool_calls_used: charged calls"),
    ("tool_calls_limit", "int64", "budget.tool_calls_limit"),
    ("sim_seconds_used", "float64", "budget.sim_seconds_used: simulated seconds"),
    ("sim_seconds_limit", "float64", "budget.sim_seconds_limit"),
    ("wall_seconds_used", "float64", "budget.wall_seconds_used: wall seconds charged to the agent"),
    ("wall_seconds_limit", "float64", "budget.wall_seconds_limit"),
    ("physics_steps", "int64", "budget.physics_steps"),
    ("sim_dt", "float64", "budget.sim_dt: the simulator's timestep, seconds"),
    ("wall_seconds", "float64", "timing.wall_seconds: the whole attempt, wall clock"),
    ("setup_seconds", "float64", "timing.setup_seconds: building its world"),
    ("charged_calls", "int64", "counts.charged_calls"),
    ("observations", "int64", "counts.observations: images shown to the agent"),
    ("tool_errors", "int64", "counts.tool_errors: exceptions raised while serving the agent's calls"),
    ("program_calls", "int64", "charged run_code calls"),
    ("internal_calls", "int64", "robot calls made from inside run_code programs"),
    ("cost_usd", "float64", "provider cost, from the model_usage_total event (or model_turn events); null when none is recorded"),
    ("input_tokens", "int64", "model_usage_total input_tokens (null when not recorded)"),
    ("output_tokens", "int64", "model_usage_total output_tokens (null when not recorded)"),
    ("wait_seconds", "float64", "provider latency and waiting, seconds (null when not recorded)"),
    ("subgoals_attained", "int64", "checkpoints: subgoals attained (null: none declared or not evaluated)"),
    ("subgoals_total", "int64", "checkpoints: subgoals declared"),
    ("subgoal_coverage", "float64", "checkpoints.subgoal_coverage: attained fraction"),
    ("spatial_attained", "int64", "checkpoints: spatial checkpoints attained"),
    ("spatial_total", "int64", "checkpoints: spatial checkpoints declared"),
    ("spatial_coverage", "float64", "checkpoints.spatial_coverage: attained fraction"),
    ("checkpoints_error", "string", "checkpoints.error: why checkpoints could not be evaluated (null: they were)"),
    ("infra_retries", "int64", "tries the sweep ran again for infrastructure failures before this one"),
    ("cab_version", "string", "versions.cab"),
    ("instruction", "string", "the task instruction the agent got"),
)

# (column, type, meaning): the schema of calls.parquet, in column order
CALL_COLUMNS: tuple[tuple[str, str, str], ...] = (
    ("attempt_key", "string", "the attempt (attempts.parquet attempt_key)"),
    ("seq", "int64", "the event's seq in events.jsonl (unique within an attempt, increasing)"),
    ("kind", "string", "call (made by the agent) or internal_call (made from inside a run_code program)"),
    ("tool", "string", "the tool called"),
    ("call_index", "int64", "the charged call it is (1-based) or, for an internal call and done, the charged call it came with"),
    ("charged", "bool", "whether it counted against the tool-call budget (done and internal calls do not)"),
    ("status", "string", "the action's status (SUCCESS, ABORTED, FAILED, ...; null for a tool that is no action)"),
    ("error_code", "string", "the error code the agent got (invalid_tool_arguments, tool_error, observation_unavailable, ...), null if none"),
    ("error", "string", "the error message the agent got (first 500 characters), null if none"),
    ("physics_steps", "int64", "physics steps the call advanced (a run_code call's include those of its internal calls)"),
    ("physics_step_end", "int64", "the physics step when it returned (null where not recorded: done)"),
    ("sim_seconds", "float64", "simulated seconds the call advanced (physics_steps x sim_dt)"),
    ("sim_time_end", "float64", "simulated time when it returned, seconds (physics_step_end x sim_dt)"),
    ("wall_seconds", "float64", "wall seconds serving it took (null for internal calls: not recorded)"),
    ("t_wall", "float64", "wall seconds since the attempt's recorder started, when the event was written"),
    ("n_observations", "int64", "images it returned"),
    ("obs_ids", "string", "the ids of those images (observations/<id>.png), as a JSON list"),
    ("program", "string", "run_code: the program's file in programs/"),
    ("arguments", "string", "the arguments as the agent sent them, as JSON text"),
)

CALL_EVENT_KINDS = ("call", "internal_call")


def _arrow_schema(columns):
    import pyarrow as pa

    types = {"string": pa.string(), "int64": pa.int64(), "float64": pa.float64(), "bool": pa.bool_()}
    return pa.schema([(name, types[t]) for name, t, _ in columns])


def _require_pyarrow():
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError as e:
        raise MissingDependency("pyarrow", "pip install 'cab[export]' (in a checkout: pip install -e '.[export]')") from e


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else None


def _int(v: Any) -> int | None:
    return int(v) if isinstance(v, int) and not isinstance(v, bool) else None


def _key(rel: str, d: Path) -> str:
    return d.resolve().name if rel in ("", ".") else rel


def attempt_row(a, key: str) -> dict:
    """One row of attempts.parquet (:data:`ATTEMPT_COLUMNS`) from a finished attempt
    (:class:`cab_core.analysis.attempts.Attempt`)."""
    r, m = a.result, AttemptMeasures.of(a)
    verdict, budget, timing = r.get("verdict") or {}, r.get("budget") or {}, r.get("timing") or {}
    counts, claim, term = r.get("counts") or {}, r.get("claim") or {}, r.get("termination") or {}
    decided = verdict.get("margin")
    decided = decided if isinstance(decided, dict) else {}
    pert = r.get("perturbation")
    pert = pert if isinstance(pert, dict) else {}
    fork = r.get("fork")
    fork = fork if isinstance(fork, dict) else {}
    ck = r.get("checkpoints")
    ck = ck if isinstance(ck, dict) else {}
    ok_ck = bool(ck) and not ck.get("error")
    subgoals, spatial = (ck.get("subgoals") or [], ck.get("spatial") or []) if ok_ck else ([], [])
    usage: dict = next((e for e in a.events if e.get("kind") == "model_usage_total"), {})
    agent = r.get("agent")
    serving = (agent.get("serving") if isinstance(agent, dict) else None) or {}
    return {
        "attempt_key": key, "config": a.config, "model": r.get("model"), "harness": r.get("harness"),
        "sim": r.get("sim"), "embodiment": r.get("embodiment"), "planner": r.get("planner"), "task": r.get("task"),
        "seed": _int(r.get("seed")), "attempt": _int(r.get("attempt")),
        "agent_clients": ", ".join(m.clients) or None,
        "serving_engine": serving.get("engine"), "serving_version": serving.get("version"),
        "salvaged_calls": m.server_side.get("salvaged_calls", 0),
        "perturbation_seed": _int(pert.get("seed")),
        "perturbation_position_m": _num(pert.get("position_m")), "perturbation_angle_deg": _num(pert.get("angle_deg")),
        "perturbation_physics_fraction": _num(pert.get("physics_fraction")),
        "fork_parent": fork.get("parent"), "fork_at": _int(fork.get("at")),
        "fork_exact": fork.get("exact") if isinstance(fork.get("exact"), bool) else None,
        "fork_max_tcp_error_m": _num(fork.get("max_tcp_error_m")),
        "success": verdict.get("success") if isinstance(verdict.get("success"), bool) else None,
        "scoring": verdict.get("scoring") or r.get("scoring"),
        "margin_predicate": decided.get("predicate"), "margin_fraction": _num(decided.get("fraction")),
        "borderline": decided.get("borderline") if isinstance(decided.get("borderline"), bool) else None,
        "success_claim": claim.get("success_claim") if isinstance(claim.get("success_claim"), bool) else None,
        "claim": m.claim, "claim_report": claim.get("report"),
        "termination_reason": term.get("reason"), "termination_detail": term.get("detail"), "stopping": m.stopping,
        "tool_calls_used": _int(budget.get("tool_calls_used")), "tool_calls_limit": _int(budget.get("tool_calls_limit")),
        "sim_seconds_used": _num(budget.get("sim_seconds_used")), "sim_seconds_limit": _num(budget.get("sim_seconds_limit")),
        "wall_seconds_used": _num(budget.get("wall_seconds_used")),
        "wall_seconds_limit": _num(budget.get("wall_seconds_limit")),
        "physics_steps": _int(budget.get("physics_steps")), "sim_dt": _num(budget.get("sim_dt")),
        "wall_seconds": _num(timing.get("wall_seconds")), "setup_seconds": _num(timing.get("setup_seconds")),
        "charged_calls": _int(counts.get("charged_calls")), "observations": _int(counts.get("observations")),
        "tool_errors": _int(counts.get("tool_errors")),
        "program_calls": m.program_calls,
        "internal_calls": sum(1 for e in a.events if e.get("kind") == "internal_call"),
        "cost_usd": m.cost_usd, "input_tokens": _int(usage.get("input_tokens")),
        "output_tokens": _int(usage.get("output_tokens")), "wait_seconds": m.wait_seconds,
        "subgoals_attained": sum(1 for s in subgoals if s.get("attained")) if subgoals else None,
        "subgoals_total": len(subgoals) if subgoals else None,
        "subgoal_coverage": _num(ck.get("subgoal_coverage")) if subgoals else None,
        "spatial_attained": sum(1 for s in spatial if s.get("attained")) if spatial else None,
        "spatial_total": len(spatial) if spatial else None,
        "spatial_coverage": _num(ck.get("spatial_coverage")) if spatial else None,
        "checkpoints_error": ck.get("error") if ck else None,
        "infra_retries": m.infra_retries, "cab_version": (r.get("versions") or {}).get("cab"),
        "instruction": r.get("instruction"),
    }


def call_rows(a, key: str) -> list[dict]:
    """The rows of calls.parquet (:data:`CALL_COLUMNS`) of one attempt: its call and internal_call
    events, in order."""
    dt = _num((a.result.get("budget") or {}).get("sim_dt"))
    rows, charged = [], 0
    for e in a.events:
        kind = e.get("kind")
        if kind not in CALL_EVENT_KINDS:
            continue
        is_charged = kind == "call" and e.get("charged", True) is not False
        charged += is_charged
        result = e.get("result") if isinstance(e.get("result"), dict) else {}
        steps = _int(e.get("physics_steps")) or 0
        end = _int(e.get("physics_step_end"))
        sim_s = _num(e.get("sim_seconds"))
        if sim_s is None and dt is not None:
            sim_s = round(steps * dt, 6)
        error = result.get("error")
        obs = [str(o) for o in e.get("obs_ids") or []]
        rows.append({
            "attempt_key": key, "seq": _int(e.get("seq")), "kind": kind, "tool": e.get("tool"),
            "call_index": charged + (kind == "internal_call"), "charged": is_charged,
            "status": e.get("status") if isinstance(e.get("status"), str) else None,
            "error_code": result.get("code") if isinstance(result.get("code"), str) else None,
            "error": (error if isinstance(error, str) else json.dumps(error))[:ERROR_TEXT_LIMIT] if error else None,
            "physics_steps": steps, "physics_step_end": end, "sim_seconds": sim_s,
            "sim_time_end": round(end * dt, 6) if end is not None and dt is not None else None,
            "wall_seconds": _num(e.get("wall_seconds")), "t_wall": _num(e.get("t_wall")),
            "n_observations": len(obs), "obs_ids": json.dumps(obs),
            "program": result.get("program") if e.get("tool") == "run_code" and isinstance(result.get("program"), str) else None,
            "arguments": json.dumps(e.get("arguments"), sort_keys=True, default=str),
        })
    return rows


def _write_parquet(rows: list[dict], columns, path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist(rows, schema=_arrow_schema(columns))
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def export_parquet(root: Path, out: Path | None = None) -> dict:
    """``attempts.parquet`` and ``calls.parquet`` of every finished attempt below ``root`` (written
    to ``out``, default ``root``). Returns what was written and what was left out."""
    _require_pyarrow()
    s = scan(root)
    out = Path(out) if out is not None else Path(root)
    out.mkdir(parents=True, exist_ok=True)
    attempts, calls = [], []
    for a in s.attempts:
        key = _key(a.rel, a.dir)
        attempts.append(attempt_row(a, key))
        calls += call_rows(a, key)
    _write_parquet(attempts, ATTEMPT_COLUMNS, out / ATTEMPTS_FILE)
    _write_parquet(calls, CALL_COLUMNS, out / CALLS_FILE)
    return {"attempts": len(attempts), "calls": len(calls), "files": [out / ATTEMPTS_FILE, out / CALLS_FILE],
            "in_flight": s.in_flight, "excluded": s.excluded, "problems": s.problems}


def exporters() -> dict[str, Callable]:
    """The installed exporter plugins (hook ``cab_record_exporters``), by format."""
    return registry("record_exporters")


def sweep_exporters() -> dict[str, Callable]:
    """The installed sweep exporter plugins (hook ``cab_sweep_exporters``), by format."""
    return registry("sweep_exporters")


def _python_refused(requires: str) -> str | None:
    """``requires`` (a ``Requires-Python`` specifier) when this interpreter does not satisfy it."""
    try:
        from packaging.specifiers import InvalidSpecifier, SpecifierSet
    except ImportError:  # pragma: no cover - packaging comes with pip
        return None
    try:
        ok = platform.python_version() in SpecifierSet(requires)
    except InvalidSpecifier:
        return None
    return None if ok else requires


def missing_exporter(fmt: str, installed: list[str]) -> str:
    """One line: the format is not installed, what is, and how to install it (or, for a plugin of
    this checkout whose ``requires-python`` this interpreter does not meet, which Python it needs)."""
    here = Path(__file__).resolve().parents[2] / "plugins" / f"export_{fmt}"
    meta = here / "pyproject.toml"
    try:  # the line itself: tomllib is Python 3.11's, and cab runs on 3.10
        found = re.search(r'^requires-python\s*=\s*"([^"]+)"', meta.read_text(), re.M) if meta.is_file() else None
    except OSError:
        found = None
    refused = _python_refused(found.group(1)) if found else None
    if refused:
        return (f"no exporter {fmt!r} is installed: its plugin ({here.name}) needs Python {refused} and this is "
                f"Python {platform.python_version()}; set up a venv of such a Python (PYTHON=3.12 "
                f"CAB_VENV=.venv-py3.12 bash scripts/install.sh installs it there) and run cab-export from it")
    how = (f"pip install -e {here}" if meta.is_file()
           else f"pip install the plugin that provides it (a distribution such as cab-export-{fmt})")
    return f"no exporter {fmt!r} is installed (installed: {', '.join(installed)}); install it with: {how}"


def export_each(export: Callable, root: Path, out: Path | None = None, echo=print) -> dict:
    """``export(attempt_dir, out_dir)`` for every finished attempt below ``root``: ``out_dir`` is the
    attempt's folder, or under ``out`` its path relative to ``root``. An attempt it fails on is one
    line and the others go on (``failed``)."""
    s = scan(root)
    written, failed = [], []
    for a in s.attempts:
        target = a.dir if out is None else (Path(out) / a.rel if a.rel not in ("", ".") else Path(out))
        try:
            paths = export(a.dir, target)
        except MissingDependency:
            raise
        except Exception as e:  # one attempt's failure: named, the others go on
            failed.append((a.rel, f"{type(e).__name__}: {e}"))
            echo(f"{_key(a.rel, a.dir)}: failed: {type(e).__name__}: {e}")
            continue
        for p in paths or []:
            p = Path(p)
            written.append(p)
            echo(f"{_key(a.rel, a.dir)}: {p} ({p.stat().st_size / 1024:.0f} KiB)")
    return {"attempts": len(s.attempts), "written": written, "failed": failed, "in_flight": s.in_flight,
            "excluded": s.excluded, "problems": s.problems}


def _left_out(res: dict) -> str:
    parts = []
    if res["in_flight"]:
        parts.append(f"{len(res['in_flight'])} unfinished")
    if res["excluded"]:
        parts.append(f"{len(res['excluded'])} not scored ("
                     + "; ".join(f"{d}: {why}" for d, why in res["excluded"][:3])
                     + ("; ..." if len(res["excluded"]) > 3 else "") + ")")
    if res["problems"]:
        parts.append(f"{len(res['problems'])} unreadable ({'; '.join(f'{d}: {p}' for d, p in res['problems'][:3])})")
    return f"; left out: {', '.join(parts)}" if parts else ""


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        prog="cab-export",
        description="Export attempt records: 'parquet' writes a sweep as attempts.parquet and calls.parquet; "
                    "any other format is an installed exporter plugin's, run on every finished attempt "
                    "(docs/export.md).",
        epilog="formats: parquet, leaderboard, or an exporter plugin's (cab-export --list)")
    ap.add_argument("format", nargs="?", help="parquet, or an installed exporter's name")
    ap.add_argument("dir", nargs="?", type=Path, help="an attempt folder or a folder of attempts (a sweep)")
    ap.add_argument("--out", type=Path, default=None,
                    help="where to write (default: the folder itself; for an exporter, each attempt's folder)")
    ap.add_argument("--as", dest="labels", action="append", metavar="CONFIG=NAME",
                    help="leaderboard and sweep exporters: take configuration CONFIG of the sweep as the paper's "
                         "configuration NAME (as cab-report --against paper --as); repeatable")
    ap.add_argument("--list", action="store_true", help="list the formats installed and exit")
    a = ap.parse_args(argv)
    try:
        installed = [PARQUET, LEADERBOARD] + sorted({*exporters(), *sweep_exporters()})
        if a.list:
            print("\n".join(installed))
            return
        if not a.format or a.dir is None:
            ap.error("a format and a folder are needed (cab-export parquet <sweep dir>)")
        if not a.dir.is_dir():
            raise ConfigError(f"{a.dir} is not a directory")
        if a.format == PARQUET:
            res = export_parquet(a.dir, a.out)
            for p in res["files"]:
                print(f"{p} ({p.stat().st_size / 1024:.0f} KiB)")
            print(f"{res['attempts']} attempts, {res['calls']} calls{_left_out(res)}")
            if not res["attempts"]:
                sys.exit(1)
            return
        if a.format == LEADERBOARD:
            rows = leaderboard.rows(a.dir, report.build(a.dir), summary.published(), parse_labels(a.labels))
            path = leaderboard.write(rows, Path(a.out or a.dir) / leaderboard.FILE)
            paper = sum(r["name_in_paper"] is not None for r in rows)
            print(f"{path}: {len(rows)} configurations ({paper} with a paper configuration), "
                  f"{sum(r['attempts'] for r in rows)} attempts")
            if not rows:
                sys.exit(1)
            return
        whole = sweep_exporters()
        if a.format in whole:
            out = Path(a.out or a.dir)
            data = summary.sweep_data(a.dir, report.build(a.dir), summary.published(), parse_labels(a.labels))
            paths = [Path(p) for p in whole[a.format](data, out) or []]
            for p in paths:
                print(f"{p} ({p.stat().st_size / 1024:.0f} KiB)")
            print(f"{a.format}: {len(paths)} files")
            if not paths:
                sys.exit(1)
            return
        registered = exporters()
        if a.format not in registered:
            raise ConfigError(missing_exporter(a.format, installed))
        res = export_each(registered[a.format], a.dir, a.out)
        print(f"{a.format}: {len(res['written'])} files from {res['attempts']} attempts"
              + (f", {len(res['failed'])} failed" if res["failed"] else "") + _left_out(res))
        if res["failed"] or not res["attempts"]:
            sys.exit(1)
    except CabError as e:
        print(f"cab-export: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
