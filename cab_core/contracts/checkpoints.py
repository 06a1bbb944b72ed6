"""The checkpoint vocabulary tasks declare with (paper §"Checkpoint definitions"): spatial rules,
regions for the TCP around references that follow moving objects, and the region tests. A task
implements

    def subgoals(self, w: WorldView) -> list[bool]                  # catalog order
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]   # catalog order

Conditions are in centimetres as in the catalog; deltas are TCP minus reference. They are evaluated
from an attempt's records by :mod:`cab_core.attempt.engine.checkpoint_scoring`.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

Reference = Callable[["object"], Sequence[float]]  # (WorldView-like) -> world xyz, metres
Test = Callable[[np.ndarray], bool]  # delta (cm, TCP - reference) -> match


def _within(v: float, lim) -> bool:
    if lim is None:
        return True
    if isinstance(lim, (int, float)):
        return bool(abs(v) <= lim)
    lo, hi = lim
    return bool((lo is None or v >= lo) and (hi is None or v <= hi))


def box(dx=None, dy=None, dz=None) -> Test:
    """|Δx| <= dx (a number) or Δx in [lo, hi] (a pair, either end None); likewise y and z."""
    return lambda d: _within(d[0], dx) and _within(d[1], dy) and _within(d[2], dz)


def cylinder(dxy: float, dz=None) -> Test:
    """d_xy <= dxy and Δz within ``dz`` (number: |Δz| <=; pair: range)."""
    return lambda d: bool(float(np.hypot(d[0], d[1])) <= dxy) and _within(d[2], dz)


def sphere(d3: float) -> Test:
    return lambda d: bool(float(np.linalg.norm(d)) <= d3)


def annulus(radius_cm: float, drho: float, dz=None) -> Test:
    """|ρ - radius| <= drho around the reference (ρ = horizontal distance), Δz within ``dz``."""
    return lambda d: bool(abs(float(np.hypot(d[0], d[1])) - radius_cm) <= drho) and _within(d[2], dz)


@dataclass(frozen=True)
class SpatialRule:
    """One spatial checkpoint. ``arm``: "left", "right" or "either". ``reference(w)`` gives the
    world point (metres) the TCP is compared with, read from the state at that moment (so it follows
    moving objects). ``prerequisites``: indices (0-based, this task's list) that must have matched
    earlier. ``lift_above_cm``: instead of a region, a relative lift: the same arm's TCP z must exceed
    its z at the matched prerequisite by more than this (XY and upper z unrestricted); ``reference``
    is then unused."""
    name: str
    arm: str
    reference: Reference | None
    test: Test | None
    prerequisites: tuple[int, ...] = ()
    lift_above_cm: float | Callable[[object], float] | None = None
    any_prerequisite: bool = False  # the catalog's "1 or 2": one matched prerequisite suffices

    def ready(self, matched: list) -> bool:
        if not self.prerequisites:
            return True
        done = [matched[j] is not None for j in self.prerequisites]
        return any(done) if self.any_prerequisite else all(done)
