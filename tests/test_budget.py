import pytest

from cab_core.attempt.budget import BudgetLedger
from cab_core.errors import BudgetExhausted


def ledger(calls=3, sim_s=1.0, wall_s=100.0):
    return BudgetLedger.create(calls, sim_s, wall_s, dt=1 / 250)


def test_tool_calls_run_out_at_the_next_boundary():
    b = ledger(calls=2)
    for _ in range(2):
        b.check_before_call()
        b.charge_call()
    assert b.remaining()["tool_calls_remaining"] == 0
    with pytest.raises(BudgetExhausted) as e:
        b.check_before_call()
    assert e.value.reason == "tool_budget"


def test_sim_budget_counts_physics_steps_and_floor_rule():
    b = ledger(sim_s=1.0)
    assert b.step_limit() == 250
    b.charge_steps(249)
    b.check_before_call()
    assert b.remaining()["sim_seconds_remaining"] == pytest.approx(0.004)
    b.charge_steps(10)  # the crossing action completes
    assert b.summary()["physics_steps"] == 259
    assert b.exhausted_reason() == "sim_budget"
    with pytest.raises(BudgetExhausted) as e:
        b.check_before_call()
    assert e.value.reason == "sim_budget"


def test_wall_budget_and_credit(monkeypatch):
    b = ledger(wall_s=10.0)
    t = [1000.0]
    monkeypatch.setattr("cab_core.attempt.budget.time.monotonic", lambda: t[0])
    b._t0 = 1000.0
    t[0] = 1011.0
    assert b.exhausted_reason() == "wall_budget"
    b.credit_wall(5.0)  # provider outage is not charged
    assert b.exhausted_reason() is None
    b.credit_wall(100.0)  # capped at one extra wall budget
    assert b.summary()["wall_seconds_credited"] == 10.0


def test_summary_keys():
    s = ledger().summary()
    for k in ("tool_calls_used", "tool_calls_limit", "sim_seconds_used", "sim_seconds_limit", "physics_steps"):
        assert k in s
