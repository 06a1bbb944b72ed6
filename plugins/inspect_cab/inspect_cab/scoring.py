"""cab's verdict as Inspect's score, from the attempt's records alone.

The scorer reads the sample's attempt folder (``cab_attempt_dir`` in the sample's metadata): its
``result.json`` (the hidden verifier's verdict, written by cab) and, for a failure, the failure
stage that ``cab-report`` gives it (:class:`cab_core.analysis.failure.Classifier`, from the
privileged snapshots; no simulator). ``inspect score`` therefore rescores a log wherever its
attempt folders are readable, without running anything. An attempt whose record is missing or
excluded (an infrastructure failure, an interruption) raises: a sample error, never a score.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from inspect_ai.scorer import CORRECT, INCORRECT, Score, Target, value_to_float
from inspect_ai.solver import TaskState

from cab_core.analysis.attempts import Attempt

from .attempt import AttemptFailed, read_result
from .task import ATTEMPT_DIR


def score_of(folder: Path) -> Score:
    """The :class:`Score` of the attempt recorded in ``folder``."""
    from cab_core.analysis.failure import Classifier

    result = read_result(folder)
    verdict = result.get("verdict") or {}
    term = result.get("termination") or {}
    claim = result.get("claim") or {}
    budget = result.get("budget") or {}
    stage, why = Classifier()(Attempt.load(folder))
    success = bool(verdict.get("success"))
    metadata: dict[str, Any] = {
        "attempt_dir": str(folder),
        "success": success,
        "termination": term.get("reason"),
        "success_claim": claim.get("success_claim"),
        "predicates": verdict.get("predicates"),
        "margins": verdict.get("margins"),
        "margin": verdict.get("margin"),
        "failure_stage": stage,
        "failure_detail": why or None,
        "checkpoints": result.get("checkpoints"),
        "tool_calls": budget.get("tool_calls_used"),
        "tool_calls_limit": budget.get("tool_calls_limit"),
        "sim_seconds": budget.get("sim_seconds_used"),
        "sim_seconds_limit": budget.get("sim_seconds_limit"),
        "model": result.get("model"),
        "task": result.get("task"),
        "seed": result.get("seed"),
        "sim": result.get("sim"),
    }
    report = claim.get("report")
    claimed = claim.get("success_claim")
    answer = None if claimed is None else f"success_claim={str(claimed).lower()}" + (f": {report}" if report else "")
    return Score(value=CORRECT if success else INCORRECT, answer=answer,
                 explanation=f"{term.get('reason')}: {term.get('detail')}", metadata=metadata)


async def score_state(state: TaskState, target: Target) -> Score:
    folder = state.metadata.get(ATTEMPT_DIR)
    if not folder:
        raise AttemptFailed(f"sample {state.sample_id} names no cab attempt folder ({ATTEMPT_DIR})")
    return score_of(Path(folder))


def wilson_bounds(values: list[float]) -> tuple[float, float]:
    """The 95% Wilson interval of the success rate, from cab's own function. Each value is a
    sample's success (1 or 0), or its mean over epochs: their sum counts as the successes."""
    from cab_core.analysis.measures import wilson

    return wilson(sum(values), len(values))  # type: ignore[arg-type]


def as_floats(scores: list[Any]) -> list[float]:
    to_float = value_to_float()
    return [to_float(s.score.value) for s in scores]
