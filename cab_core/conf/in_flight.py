"""How many attempts a sweep keeps in flight on this machine by default (``sweep.max_in_flight: null``).

A model-bound sweep (a model agent: its attempts spend most of their time waiting on a provider)
keeps as many attempts in flight as memory holds: ``min(sweep.in_flight_cap, floor((available memory -
sweep.memory_reserve_mb) / slot memory))``, the slot memory being the largest ``slot_memory_mb`` of the
sweep's simulators (each simulator's yaml documents its measured figure; :data:`DEFAULT_SLOT_MEMORY_MB`
for one that does not). A CPU-bound sweep (only model-free agents: oracle, idle, scripted, human: a
config with ``agent:`` set) keeps one attempt per core, as before. An integer ``sweep.max_in_flight``
is used as it is. The local launcher's ``n_jobs`` (hydra_plugins.cab_launcher) is this figure (the resolver ``cab.in_flight``,
cab_core.config), so a sweep's plan reads it from ``hydra.launcher.n_jobs``.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

DEFAULT_SLOT_MEMORY_MB = 512  # a simulator whose yaml gives no slot_memory_mb


def available_memory_mb() -> float:
    """Memory available to new processes now (``MemAvailable`` of /proc/meminfo), in MiB."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") / 2**20


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


@dataclass(frozen=True)
class InFlight:
    """The attempts in flight a sweep uses, and why."""
    n: int
    why: str


def in_flight(max_in_flight: int | None, model_bound: bool, slot_memory_mb: float, *, cap: int, reserve_mb: float,
              available_mb: float | None = None, n_cores: int | None = None) -> InFlight:
    """The attempts in flight (see the module's docstring); ``available_mb`` and ``n_cores`` default
    to this machine's now."""
    if max_in_flight is not None:
        return InFlight(int(max_in_flight), "sweep.max_in_flight")
    n_cores = cores() if n_cores is None else n_cores
    if not model_bound:
        return InFlight(n_cores, f"model-free agents: one per core ({n_cores})")
    free = available_memory_mb() if available_mb is None else available_mb
    fit = math.floor((free - reserve_mb) / slot_memory_mb)
    n = max(1, min(cap, fit))
    return InFlight(n, f"model-bound: min(cap {cap}, ({free:.0f} MiB available - {reserve_mb:.0f} reserved) / "
                       f"{slot_memory_mb:.0f} MiB per slot = {fit})")
