"""What a harness is, and what it may use of the attempt it drives: the one protocol between the
harnesses and the attempt.

A harness (hook ``cab_harnesses``: ``{name: factory(cfg)}``, :class:`HarnessFactory`) runs an agent
through one attempt. The runner (:func:`cab_core.attempt.runner.run_attempt`) creates it, calls the
optional members it has (:class:`HarnessHooks`: ``preflight``, then ``before_build``), builds the
attempt, and calls :meth:`Harness.run` with the running attempt seen as an :class:`AttemptSession`
(:class:`cab_core.attempt.engine.episode.Episode` is one). A harness uses nothing of the attempt beyond
:class:`AttemptSession`; a model-free agent of the core's ``direct`` harness (hook ``cab_agents``)
is a :class:`ModelFreeAgent` and gets the same session.

The types the protocol names are this module's own: :class:`ToolResponse` (what a call returns),
:class:`SessionSpec` (the attempt's settings a harness reads; the engine's
:class:`cab_core.attempt.spec.AttemptSpec` has them) and :class:`ForkOrigin` (where a fork started;
:class:`cab_core.attempt.fork.ForkPoint` is one), so nothing here points up into the engine.

Protocols and one plain dataclass: nothing here runs, and this module imports nothing of cab at run
time.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    import numpy as np

    from cab_core.contracts.task import Task
    from cab_core.contracts.verifier import WorldView


@dataclass
class ToolResponse:
    """What an agent gets back from one call."""
    name: str
    payload: dict
    obs_ids: list[str]
    ended: bool = False
    status: str | None = None


@dataclass
class ModelCheck:
    """What a harness found out about a model configuration before any attempt runs
    (:meth:`HarnessHooks.check_model`): the plan of a sweep prints it, the pre-flight refuses a
    configuration with ``problems``. ``None`` in a field: not known or does not apply."""
    #: the model provider (the name of a ``cab_model_providers`` entry) and the endpoint it talks to
    provider: str | None = None
    endpoint: str | None = None
    #: the environment variable of the credential, and whether it is set (None: no key needed)
    key_env: str | None = None
    key_present: bool | None = None
    #: whether the endpoint answered, and whether it lists the model (where it has a model list)
    reachable: bool | None = None
    model_listed: bool | None = None
    #: what a probe of the endpoint found (a local server's capability profile), JSON-able
    capabilities: dict | None = None
    #: each problem as one line that names the fix; a configuration with any cannot run
    problems: list[str] = field(default_factory=list)


@runtime_checkable
class SessionSpec(Protocol):
    """The resolved attempt, as far as a harness reads it (``session.spec``)."""

    #: the task's name, the seed of its instance and the attempt's number at that seed
    task: str
    seed: int
    attempt: int
    #: the simulator's name
    sim: str
    #: the model's configuration name (``model=``), and its configuration (``model.*``)
    model: str
    model_cfg: dict
    #: the harness's name
    harness: str
    #: the attempt's record directory
    output_dir: Path
    #: the tool-call and simulated-time budgets
    budget_tool_calls: int
    budget_sim_seconds: float
    #: how many robot calls one ``run_code`` may make
    run_code_max_internal_calls: int
    #: the attempt's spend cap in USD (``budget.cost_usd``; None: none): a harness that pays for a
    #: model charges each response's cost (``ledger.charge_cost``) and sends no request once it is reached
    budget_cost_usd: float | None
    #: the sandbox's settings (``sandbox.*``)
    sandbox: dict


@runtime_checkable
class ForkOrigin(Protocol):
    """Where a fork started: the parent's records up to and including its charged call ``at``."""

    #: the parent's attempt directory
    parent: Path
    #: the parent's charged call the fork starts after
    at: int
    #: the parent's resolved configuration (its ``attempt_start`` event's ``config``)
    config: dict
    #: the parent's events up to and including charged call ``at``
    events: list[dict]


@runtime_checkable
class CallLimit(Protocol):
    """One budget of the session's ledger, as a harness reads it."""

    #: the limit (for ``tool_calls``: the number of charged calls the attempt allows)
    limit: float


@runtime_checkable
class SessionLedger(Protocol):
    """The attempt's budgets, as far as a harness reads or credits them (the episode enforces them
    itself: a harness never needs to)."""

    #: the tool-call budget; a harness sizes its own turn limit from ``tool_calls.limit``
    tool_calls: CallLimit

    def remaining(self) -> dict:
        """What every tool result shows: ``tool_calls_remaining``, ``tool_calls_limit``,
        ``sim_seconds_remaining``, ``sim_seconds_limit`` (the system prompt states them)."""
        ...

    def exhausted_reason(self) -> str | None:
        """The budget that is spent (``sim_budget``, ``wall_budget``, ``tool_budget``, ``cost_budget``),
        None while none is; a harness checks ``wall_budget`` and ``cost_budget`` between model turns,
        where no call is made."""
        ...

    def credit_wall(self, seconds: float) -> None:
        """Give back wall-clock time the harness spent waiting on a provider outage (capped at one
        extra wall budget)."""
        ...

    def charge_cost(self, usd: float) -> None:
        """Count one model response's cost against the spend cap (``budget.cost_usd``); once it is
        reached, ``exhausted_reason()`` is ``cost_budget`` and the harness ends the attempt so."""
        ...


@runtime_checkable
class EventLog(Protocol):
    """The attempt's event log (``events.jsonl``), as a harness writes to it."""

    def event(self, kind: str, **data: Any) -> dict:
        """Append one event of ``kind`` (the harness's own: model turns, usage, provider failures,
        MCP clients...) with JSON-able ``data``; returns the event as written."""
        ...


@runtime_checkable
class AttemptSession(Protocol):
    """The running attempt, as a harness (and a model-free agent) sees it."""

    #: the attempt, fully resolved (task, seed, budgets, model config, sandbox settings...); read
    #: only, except ``spec.model``, which a harness that learns who played (an MCP client naming
    #: itself) may set before the attempt finishes
    spec: SessionSpec
    #: the attempt's record directory (a harness keeps its own logs there)
    out: Path
    #: True once the attempt has ended (an ending call, a spent budget, :meth:`end`)
    ended: bool
    #: why it ended: ``{"reason": ..., "detail": ...}``; None while it runs
    termination: dict | None
    #: ``result.json`` as written once :meth:`finish` has run, else None
    result: dict | None
    #: who played, when the harness knows more than the config (``result.json`` ``agent``, the
    #: shape of :class:`cab_core.kits.harness.agent_info.AgentRecord`); set by the harness, None if unknown
    agent: dict | None
    #: the budgets (:class:`SessionLedger`)
    ledger: SessionLedger
    #: the event log (:class:`EventLog`)
    recorder: EventLog
    #: the task (privileged: only the oracle agent uses it, for ``task.oracle``)
    task: Task
    #: the privileged view of the world (only the oracle agent uses it, to compute its targets)
    world: WorldView
    #: where a fork started (``fork.from``/``fork.at``), None for an attempt that is no fork. The
    #: parent's first ``fork.at`` charged calls have been made again when :meth:`Harness.run` is
    #: called (the world is the parent's then, its observations re-taken under the same ids, so
    #: :meth:`image` shows them); a harness may rebuild its agent's context from ``fork.events``,
    #: the parent's records up to there (:func:`cab_core.kits.harness.conversation.transcript`)
    fork: ForkOrigin | None

    @property
    def instruction(self) -> str:
        """The task's instruction, as the agent is given it."""
        ...

    def tool_specs(self) -> list[dict]:
        """Every tool the agent may call: name, description and JSON schema of its arguments."""
        ...

    def call(self, name: str, args: dict | None = None) -> ToolResponse:
        """One direct tool call by the agent, executed and recorded by the attempt: charged to the
        tool-call budget (``done`` is free), refused once a budget is spent (the attempt then ends).
        Raises :class:`cab_core.errors.AttemptEnded` when the attempt has already ended."""
        ...

    def image(self, obs_id: str) -> np.ndarray:
        """The image of an observation a tool result named (``ToolResponse.obs_ids``), RGB uint8."""
        ...

    def end(self, reason: str, detail: str = "") -> None:
        """End the attempt from the harness's side (the agent stopped, a provider failed, a turn
        limit...); the first ending wins, later ones change nothing."""
        ...

    def finish(self) -> dict:
        """Score the attempt and write ``result.json`` (an attempt not yet ended ends as
        ``no_done``); returns the result. Idempotent; the runner calls it after :meth:`Harness.run`
        when the harness did not."""
        ...


@runtime_checkable
class Harness(Protocol):
    """What every harness has. Its optional members are :class:`HarnessHooks`."""

    def run(self, session: AttemptSession, model_cfg: dict) -> None:
        """Drive the agent through the attempt until it has ended (or end it: :meth:`AttemptSession.end`).
        ``model_cfg``: the model's configuration (``model.*``). An exception ends the attempt as
        ``harness_error`` (``host_fault`` for an infrastructure fault, :mod:`cab_core.attempt.engine.faults`)."""
        ...


class HarnessHooks(Protocol):
    """The optional members of a harness: the runner calls ``preflight``, ``before_build`` and
    ``close`` when a harness has them, in this order; ``check_model`` is called by the sweep's plan
    and pre-flight, before any attempt."""

    def preflight(self, model_cfg: dict) -> None:
        """Check what the harness needs (credentials, endpoints, an agent's config) before any
        simulator starts; raise :class:`cab_core.errors.ConfigError` naming what is missing."""
        ...

    def check_model(self, model_cfg: dict, network: bool = True) -> ModelCheck:
        """Everything that can be checked of ``model_cfg`` before an attempt, without a simulator:
        credentials, and with ``network`` the endpoint (it answers, it lists the model, a probe of
        its capabilities). Never raises for a problem it finds: each goes into ``problems``. The
        plan (``sweep.dry_run``) and a sweep's pre-flight call it once per configuration."""
        ...

    def before_build(self, spec: SessionSpec) -> None:
        """Called with the attempt's spec after ``preflight`` and before the world is built (a server
        can start answering its client meanwhile)."""
        ...

    def close(self) -> None:
        """Called when building the world failed after ``before_build``: release what it started."""
        ...


class HarnessFactory(Protocol):
    """A value of the ``cab_harnesses`` hook: ``factory(cfg)`` returns the :class:`Harness` of one
    attempt. Optional attribute ``speaks_on_stdio = True`` (read with ``getattr(factory,
    "speaks_on_stdio", False)``): the harness serves its agent a protocol on stdin/stdout, so
    ``cab harness=<name>`` reserves stdout for it before anything else prints (unless
    ``harness.transport=`` names another transport)."""

    def __call__(self, cfg: dict) -> Harness:
        ...


@runtime_checkable
class ModelFreeAgent(Protocol):
    """A model-free agent of the ``direct`` harness (hook ``cab_agents``: oracle, idle, scripted...)."""

    def run(self, session: AttemptSession) -> None:
        """Make the agent's calls through ``session`` until it is done or the attempt has ended."""
        ...
