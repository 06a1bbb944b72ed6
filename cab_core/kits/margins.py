"""Margins: how far inside (positive) or outside (negative) its threshold a verifier's predicate
is, so that reports can flag borderline verdicts. The constructors are the contract's
(:mod:`cab_core.contracts.verifier`), gathered here with the predicates tasks share."""
from __future__ import annotations

from collections.abc import Iterable

from cab_core.contracts.verifier import (
    Margin,
    WorldView,
    margin_above,
    margin_all,
    margin_any,
    margin_below,
    margin_within,
)

__all__ = ["Margin", "margin_above", "margin_all", "margin_any", "margin_below", "margin_within", "grippers_open"]


def grippers_open(w: WorldView, arms: Iterable[str], threshold: float) -> tuple[bool, dict[str, float], Margin]:
    """Whether every one of ``arms`` has its gripper commanded open (above ``threshold``); the
    commands as values (``gripper_<arm>``); the margin (the least open gripper's, each against the
    band above the threshold)."""
    grips = {a: w.gripper_command(a) for a in arms}
    return (all(g > threshold for g in grips.values()), {f"gripper_{a}": float(g) for a, g in grips.items()},
            margin_all(*(margin_above(g, threshold, "gripper command", 1 - threshold) for g in grips.values())))
