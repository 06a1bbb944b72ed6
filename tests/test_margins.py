"""Verdict margins (cab_core.contracts.verifier): each predicate's distance to its threshold, the margin that
decided a verdict, and when a verdict is borderline."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cab_core.attempt.engine.episode import VerdictTracker
from cab_core.contracts.verifier import (
    BORDERLINE_FRACTION,
    Evaluation,
    Margin,
    Verifier,
    deciding_margin,
    margin_above,
    margin_all,
    margin_any,
    margin_below,
    margin_within,
)

finite = st.floats(min_value=-1e3, max_value=1e3, allow_nan=False)
positive = st.floats(min_value=1e-3, max_value=1e3, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(finite, finite)
def test_below_and_above_have_the_predicates_sign(x, t):
    b, a = margin_below(x, t, "m"), margin_above(x, t, "m")
    if x != t:
        assert (b.slack > 0) == (x < t) and (a.slack > 0) == (x > t)
    assert b.slack == -a.slack and b.scale > 0 and a.scale > 0
    assert (b.measured, b.threshold) == (x, t)


@settings(max_examples=300, deadline=None)
@given(st.lists(finite, min_size=1, max_size=4), st.lists(positive, min_size=4, max_size=4))
def test_within_is_the_tightest_component(d, tols):
    tol = tols[:len(d)]
    m = margin_within(d, tol, "m")
    holds = all(abs(x) < t for x, t in zip(d, tol))
    if all(abs(x) != t for x, t in zip(d, tol)):
        assert (m.slack > 0) == holds
    assert math.isclose(m.fraction, min((t - abs(x)) / t for x, t in zip(d, tol)), rel_tol=1e-9, abs_tol=1e-12)


def test_within_one_tolerance_for_all_components():
    m = margin_within([0.01, -0.02, 0.0], 0.025, "m")
    assert m.slack == pytest.approx(0.005) and m.scale == 0.025 and m.fraction == pytest.approx(0.2)
    m = margin_within(np.array([0.0, 0.03]), (0.025, 0.05), "m")
    assert m.fraction == pytest.approx(0.4) and m.measured == pytest.approx(0.03)


def test_scale_defaults_to_the_threshold_and_never_zero():
    assert margin_above(0.9, 0.8, "gripper command").fraction == pytest.approx(0.125)
    assert margin_above(0.9, 0.8, "gripper command", 0.2).fraction == pytest.approx(0.5)
    assert margin_below(-0.1, 0.0, "m").scale == 1.0


def test_conjunction_takes_the_tightest_and_disjunction_the_widest():
    a, b = Margin(0.5, 1.0, "m"), Margin(-0.2, 0.4, "rad")
    assert margin_all(a, b) is b and margin_any(a, b) is a


def test_success_is_decided_by_its_smallest_margin():
    preds = {"on": True, "open": True, "touch": True}
    ms = {"on": Margin(0.002, 0.025, "m"), "open": Margin(0.2, 0.2, "gripper command")}
    d = deciding_margin(preds, ms, True)
    assert d["predicate"] == "on" and d["fraction"] == pytest.approx(0.08)
    assert d["borderline"] is True and d["threshold"] == BORDERLINE_FRACTION
    ms["on"] = Margin(0.01, 0.025, "m")
    assert deciding_margin(preds, ms, True)["borderline"] is False


def test_failure_flips_only_when_every_failing_predicate_does():
    preds = {"on": False, "open": False, "upright": True}
    ms = {"on": Margin(-0.001, 0.025, "m"), "open": Margin(-0.1, 0.2, "gripper command"),
          "upright": Margin(0.001, 0.1, "rad")}
    d = deciding_margin(preds, ms, False)
    assert d["predicate"] == "open" and d["fraction"] == pytest.approx(-0.5) and d["borderline"] is False
    ms["open"] = Margin(-0.01, 0.2, "gripper command")
    d = deciding_margin(preds, ms, False)
    assert d["predicate"] == "open" and d["borderline"] is True


def test_a_failure_without_a_threshold_is_never_borderline():
    preds = {"contact": False, "on": False}
    d = deciding_margin(preds, {"on": Margin(-0.0001, 0.025, "m")}, False)
    assert d == {"predicate": None, "fraction": None, "borderline": False, "threshold": BORDERLINE_FRACTION}
    assert deciding_margin({"contact": True}, {}, True)["predicate"] is None


def test_record_is_plain_data():
    r = margin_within([0.01], 0.025, "m").as_record()
    assert r == {"slack": pytest.approx(0.015), "scale": 0.025, "fraction": pytest.approx(0.6), "unit": "m",
                 "measured": pytest.approx(0.01), "threshold": 0.025}



class Rising(Verifier):
    """A latched event on a quantity the test sets: it holds above 1.0 (tolerance 0.5)."""
    scoring = "latch"

    def __init__(self):
        self.x = 0.0

    def evaluate(self, w):
        m = margin_above(self.x, 1.0, "m", 0.5)
        return Evaluation(success=self.x > 1.0, predicates={"high": self.x > 1.0}, margins={"high": m})


def test_a_latched_event_is_judged_at_its_widest_within_a_second_of_latching():
    v = Rising()
    t = VerdictTracker(v, world=None, timestep=0.01)  # the window: 1 simulated second, 100 steps
    path = {1: 0.5, 2: 1.01, 3: 1.2, 50: 1.4, 60: 0.9, 99: 1.3, 150: 1.49}  # 1.49: after the window
    for step in range(1, 160):
        v.x = path.get(step, v.x)
        t.poll(step)
    assert t.latched and t.latched_at_step == 2
    f = t.final()
    assert f["success"] is True and f["margins_at"] == "latch" and f["margins_at_step"] == 50
    assert f["margins"]["high"]["fraction"] == pytest.approx(0.8)
    assert f["margin"] == {"predicate": "high", "fraction": pytest.approx(0.8), "borderline": False,
                           "threshold": BORDERLINE_FRACTION}
    assert f["predicates"] == {"high": True}  # the final state, as before


def test_an_event_that_never_latched_has_no_deciding_margin():
    v = Rising()
    t = VerdictTracker(v, world=None, timestep=0.01)
    for step in range(1, 50):
        v.x = 0.99
        t.poll(step)
    f = t.final()
    assert f["success"] is False and f["margins_at"] == "final"
    assert f["margins"]["high"]["fraction"] == pytest.approx(-0.02)
    assert f["margin"]["predicate"] is None and f["margin"]["borderline"] is False
