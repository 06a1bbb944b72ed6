"""Typed errors. Library code raises these; only the CLI talks to a person."""
from __future__ import annotations


class CabError(Exception):
    """Base of every error cab raises on purpose."""


class ConfigError(CabError):
    """A configuration value is missing, unknown or invalid."""


class PluginError(CabError):
    """A plugin is missing, duplicated or broken."""


class MissingDependency(CabError):
    """An optional dependency is not installed; the message carries the install command."""

    def __init__(self, what: str, install: str):
        super().__init__(f"{what} is not installed; install it with: {install}")
        self.install = install


class SimulatorError(CabError):
    """The simulator failed."""


class InfrastructureFault(CabError):
    """The host itself is broken (a simulator or renderer process died or stopped answering, a device
    was lost): not the agent's doing. A sweep retries the attempt and reports exclude it
    (:mod:`cab_core.attempt.faults`)."""


class BadCommand(SimulatorError):
    """A command to the simulator is malformed (wrong shape, unknown name, non-finite value)."""


class RendererUnavailable(SimulatorError):
    """No rendering device could be started; the message holds a diagnosis and the fix."""


class PlannerError(CabError):
    """The planner failed unexpectedly (not a refusal: refusals are results)."""


class ToolArgumentError(CabError):
    """A tool was called with invalid arguments. The call is still charged."""


class BudgetExhausted(CabError):
    """A budget ran out; ``reason`` is the termination reason (tool_budget, sim_budget, wall_budget)."""

    def __init__(self, reason: str, message: str = ""):
        super().__init__(message or reason)
        self.reason = reason


class SandboxUnavailable(CabError):
    """Confinement was required but cannot be provided on this machine."""


class AttemptEnded(CabError):
    """Raised to an agent that calls a tool after its attempt ended."""


class ObservationUnavailable(CabError):
    """A camera could not deliver an image (e.g. a physics-only build); the attempt goes on."""


class RecordError(CabError):
    """An attempt's records are missing, corrupt or inconsistent (analysis reports and skips it)."""


def closest(word: str, options, cutoff: float = 0.6) -> list[str]:
    """Up to three of ``options`` that look like ``word`` (difflib), best first: the "did you
    mean" of an error message."""
    import difflib

    return difflib.get_close_matches(str(word), [str(o) for o in options], n=3, cutoff=cutoff)
