"""How an attempt ended, read as a recovery: a fork played by a stage-aware reference solution
either recovered the task, was not recoverable (and why), or failed without a reason. The sweep's
supervisor reads it for its batches of forks, the recoverability report for its tables."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from cab_core.kits.jsonfiles import read_json_object, read_jsonl

BUDGET_ENDINGS = ("tool_budget", "sim_budget", "wall_budget", "cost_budget")


def recovery(attempt_dir: Path) -> dict:
    """How an attempt ended, as a recovery (a fork played by a stage-aware reference solution):
    ``outcome`` "recovered" (the task succeeded), "not_recoverable" (with ``kind`` and ``reason``:
    what the solution reported, or a budget that ran out) or "unexplained" (it failed and gave no
    reason: a defect of the reference solution). The verdict decides: a fork whose solution said
    "not recoverable" while the verifier judged the task solved (an event verifier latched before the
    fork point, say) is "recovered", with what the solution said under ``oracle_said`` so that the
    solution's mistaken stage check can be found."""
    d = Path(attempt_dir)
    result = read_json_object(d / "result.json")
    term = result.get("termination") or {}
    said = [e for e in read_jsonl(d / "events.jsonl") if e.get("kind") == "oracle_not_recoverable"]
    if (result.get("verdict") or {}).get("success"):
        out: dict[str, Any] = {"outcome": "recovered", "kind": None, "reason": None}
        if said:
            out["oracle_said"] = {"kind": said[-1].get("reason_kind"), "reason": said[-1].get("reason")}
        return out
    if said:
        return {"outcome": "not_recoverable", "kind": said[-1].get("reason_kind"), "reason": said[-1].get("reason")}
    if term.get("reason") in BUDGET_ENDINGS:
        return {"outcome": "not_recoverable", "kind": "budget", "reason": term.get("detail") or term.get("reason")}
    return {"outcome": "unexplained", "kind": term.get("reason"), "reason": term.get("detail")}
