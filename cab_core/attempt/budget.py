"""Budgets as limit objects (limit, usage, remaining), enforced in the host, never by prompt.

- tool calls: each direct call or run_code submission costs one; done is free. A call made when
  none remain is not executed and the attempt ends (``tool_budget``).
- simulated seconds: every physics step costs ``dt``, inside programs too. The action that crosses
  the limit completes; the attempt then ends at the next tool boundary (``sim_budget``).
- wall seconds: checked at each dispatch (``wall_budget``); time the host reports as provider
  outage is credited back, capped at one extra wall budget.
- internal calls: a cap on tool calls inside one run_code program (not charged to the episode).
- spend (``budget.cost_usd``, null: none): the harness charges each model response's cost
  (:meth:`BudgetLedger.charge_cost`); once the spend reaches the cap the harness sends no further
  request and the attempt ends (``cost_budget``, scored like the other budgets). The calls of the
  response that reached it are made: they are paid for.

The values a configuration may give (``budget.*``: positive, or null for the task's catalog budget)
are the schema's (cab_core.conf.schema.BudgetConfig).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

from cab_core.errors import BudgetExhausted


@dataclass
class Limit:
    name: str
    limit: float
    usage: float = 0.0

    @property
    def remaining(self) -> float:
        return max(0.0, self.limit - self.usage)

    @property
    def exhausted(self) -> bool:
        return self.usage >= self.limit


@dataclass
class BudgetLedger:
    tool_calls: Limit
    sim_seconds: Limit
    wall_seconds: Limit
    run_code_internal_calls: int = 500
    dt: float = 1.0 / 250.0
    physics_steps: int = 0
    _t0: float = field(default_factory=time.monotonic)
    _wall_credit: float = 0.0
    cost_usd: Limit | None = None  # the spend cap (budget.cost_usd); None: no cap

    @classmethod
    def create(cls, tool_calls: int, sim_seconds: float, wall_seconds: float, dt: float,
               run_code_internal_calls: int = 500, cost_usd: float | None = None) -> BudgetLedger:
        return cls(Limit("tool_calls", tool_calls), Limit("sim_seconds", sim_seconds),
                   Limit("wall_seconds", wall_seconds), run_code_internal_calls, dt,
                   cost_usd=None if cost_usd is None else Limit("cost_usd", float(cost_usd)))

    # -- charging -----------------------------------------------------------------------------
    def step_limit(self) -> int:
        """Physics steps allowed: floor(budget_s / dt)."""
        return int(self.sim_seconds.limit / self.dt + 1e-9)

    def charge_steps(self, n: int) -> None:
        self.physics_steps += n
        self.sim_seconds.usage = self.physics_steps * self.dt

    def charge_call(self) -> None:
        self.tool_calls.usage += 1

    def charge_cost(self, usd: float) -> None:
        """The harness's spend on one model response (USD; counted against ``budget.cost_usd``)."""
        if self.cost_usd is not None:
            self.cost_usd.usage += max(0.0, float(usd or 0.0))

    def credit_wall(self, seconds: float) -> None:
        self._wall_credit = min(self.wall_seconds.limit, self._wall_credit + max(0.0, seconds))

    def carry_wall(self, spent: float) -> None:
        """Start the wall clock over as if ``spent`` seconds had already been used (a fork carries its
        parent's spend; the time its prefix took to re-execute is not charged)."""
        self._t0 = time.monotonic() - max(0.0, float(spent))
        self._wall_credit = 0.0
        self.update_wall()

    def wall_elapsed(self) -> float:
        return time.monotonic() - self._t0

    def update_wall(self) -> None:
        self.wall_seconds.usage = max(0.0, self.wall_elapsed() - self._wall_credit)

    # -- checks -------------------------------------------------------------------------------
    @property
    def sim_exhausted(self) -> bool:
        return self.physics_steps >= self.step_limit()

    def check_before_call(self) -> None:
        """At a tool boundary: raise if any budget is spent (the call is then not executed)."""
        self.update_wall()
        if self.sim_exhausted:
            raise BudgetExhausted("sim_budget", f"simulated-time budget of {self.sim_seconds.limit:g} s is spent")
        if self.wall_seconds.exhausted:
            raise BudgetExhausted("wall_budget", f"wall-clock budget of {self.wall_seconds.limit:g} s is spent")
        if self.tool_calls.exhausted:
            raise BudgetExhausted("tool_budget", f"tool-call budget of {int(self.tool_calls.limit)} is spent")

    def exhausted_reason(self) -> str | None:
        self.update_wall()
        if self.sim_exhausted:
            return "sim_budget"
        if self.wall_seconds.exhausted:
            return "wall_budget"
        if self.tool_calls.exhausted:
            return "tool_budget"
        if self.cost_usd is not None and self.cost_usd.exhausted:
            return "cost_budget"
        return None

    def remaining(self) -> dict:
        """What every tool result shows."""
        return {
            "tool_calls_remaining": int(self.tool_calls.remaining),
            "tool_calls_limit": int(self.tool_calls.limit),
            "sim_seconds_remaining": round(self.sim_seconds.remaining, 3),
            "sim_seconds_limit": self.sim_seconds.limit,
        }

    def summary(self) -> dict:
        self.update_wall()
        return {
            "tool_calls_used": int(self.tool_calls.usage),
            "tool_calls_limit": int(self.tool_calls.limit),
            "sim_seconds_used": round(self.sim_seconds.usage, 4),
            "sim_seconds_limit": self.sim_seconds.limit,
            "physics_steps": self.physics_steps,
            "sim_dt": self.dt,
            "wall_seconds_used": round(self.wall_seconds.usage, 3),
            "wall_seconds_limit": self.wall_seconds.limit,
            "wall_seconds_credited": round(self._wall_credit, 3),
            "run_code_internal_calls_limit": self.run_code_internal_calls,
            **({"cost_usd_used": round(self.cost_usd.usage, 6), "cost_usd_limit": self.cost_usd.limit}
               if self.cost_usd is not None else {}),
        }
