"""One protocol between the harnesses and the attempt (cab_core/contracts/harness.py): the episode
is an AttemptSession, member for member and signature for signature, and the harnesses and agents
cab ships are Harnesses and ModelFreeAgents."""
from __future__ import annotations

import inspect
from pathlib import Path

import pytest

from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.engine.builtin import DirectHarness, IdleAgent, OracleAgent
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.runner import attempt_spec
from cab_core.contracts.harness import (
    AttemptSession,
    CallLimit,
    EventLog,
    Harness,
    HarnessHooks,
    ModelFreeAgent,
    SessionLedger,
)
from cab_harness_mcp.plugin import create_mcp


def members(proto) -> dict[str, object]:
    """A protocol's own members: its annotated attributes and its methods and properties."""
    out = {name: None for name in proto.__dict__.get("__annotations__", {})}
    out.update({name: v for name, v in vars(proto).items()
                if not name.startswith("_") and (inspect.isfunction(v) or isinstance(v, property))})
    return out


def parameters(fn) -> list[tuple[str, object]]:
    return [(p.name, p.default) for p in inspect.signature(fn).parameters.values()]


def test_the_protocol_names_what_the_harnesses_use():
    assert set(members(AttemptSession)) == {
        "spec", "out", "ended", "termination", "result", "agent", "ledger", "recorder", "task", "world",
        "fork", "instruction", "tool_specs", "call", "image", "end", "finish"}
    assert set(members(SessionLedger)) == {"tool_calls", "remaining", "exhausted_reason", "credit_wall", "charge_cost"}
    assert set(members(EventLog)) == {"event"} and set(members(CallLimit)) == {"limit"}
    assert set(members(Harness)) == {"run"} and set(members(HarnessHooks)) == {"preflight", "check_model", "before_build", "close"}
    for proto in (AttemptSession, SessionLedger, EventLog, Harness, HarnessHooks, ModelFreeAgent):
        for name, v in members(proto).items():  # every member documented
            if v is not None:
                doc = (v.fget if isinstance(v, property) else v).__doc__
                assert doc and doc.strip(), f"{proto.__name__}.{name} has no docstring"
    for proto in (AttemptSession, SessionLedger, CallLimit):  # attributes: a "#:" comment above each
        lines = inspect.getsource(proto).splitlines()
        for name, v in members(proto).items():
            if v is None:
                at = next(i for i, line in enumerate(lines) if line.startswith(f"    {name}: "))
                assert lines[at - 1].strip().startswith("#:"), f"{proto.__name__}.{name} undocumented"


def test_the_episode_class_has_the_session_methods_with_their_signatures():
    """Without a simulator: the methods and properties, and the parameters each takes."""
    for name, v in members(AttemptSession).items():
        if v is None:
            continue
        mine = getattr(Episode, name, None)
        assert mine is not None, f"Episode lacks {name}"
        if isinstance(v, property):
            assert isinstance(mine, property), name
        else:
            assert parameters(mine) == parameters(v), name


def test_cabs_harnesses_and_agents_follow_the_protocol():
    assert isinstance(DirectHarness({}), Harness)
    assert isinstance(IdleAgent({}), ModelFreeAgent) and isinstance(OracleAgent({}), ModelFreeAgent)
    assert len(parameters(DirectHarness.run)) == len(parameters(Harness.run))  # (self, session, model_cfg)
    ref = pytest.importorskip("cab_harness_reference.loop")
    assert isinstance(ref.ReferenceHarness({}), Harness)
    mcp = pytest.importorskip("cab_harness_mcp.harness")
    h = mcp.McpHarness({})
    assert isinstance(h, Harness)
    for name in members(HarnessHooks):
        assert parameters(getattr(type(h), name)) == parameters(getattr(HarnessHooks, name)), name

    assert getattr(create_mcp, "speaks_on_stdio", False) is True


@pytest.mark.sim
def test_a_real_episode_is_an_attempt_session(tmp_path):
    from hydra import compose, initialize_config_module

    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(
            ["sim=mujoco", "task=click_bell", "record.video=false"]))
    with Episode.open(attempt_spec(cfg, tmp_path / "a")) as ep:
        assert isinstance(ep, AttemptSession)
        assert isinstance(ep.ledger, SessionLedger) and isinstance(ep.ledger.tool_calls, CallLimit)
        assert isinstance(ep.recorder, EventLog)
        for name in members(AttemptSession):
            assert hasattr(ep, name), name
        assert isinstance(ep.out, Path) and ep.ended is False and ep.result is None and ep.termination is None
        assert ep.fork is None  # no fork.from
        assert isinstance(ep.instruction, str) and ep.tool_specs()
        r = ep.call("capture_head")
        assert ep.image(r.obs_ids[0]).ndim == 3
        ep.end("harness_stopped", "test")
        result = ep.finish()
        assert ep.ended and ep.termination == {"reason": "harness_stopped", "detail": "test"}
        assert ep.result is result and ep.record.dump() == result
