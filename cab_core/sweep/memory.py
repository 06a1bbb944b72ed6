"""Memory of a process and of its process tree, as Linux accounts it.

PSS (proportional set size) charges each page to the processes that map it in equal shares, so the
PSS of several processes adds up to the memory they hold together: a page shared copy-on-write by N
attempt processes counts 1/N in each. RSS counts it in full in each. Read from
``/proc/<pid>/smaps_rollup`` (Linux 4.14 and later); elsewhere, or for a process that is gone, 0.
"""
from __future__ import annotations

import os
from pathlib import Path


def _rollup(pid: int) -> dict[str, float]:
    """The fields of ``/proc/<pid>/smaps_rollup`` in MiB (empty when it cannot be read)."""
    out: dict[str, float] = {}
    try:
        text = Path(f"/proc/{pid}/smaps_rollup").read_text()
    except OSError:
        return out
    for line in text.splitlines()[1:]:
        key, _, rest = line.partition(":")
        parts = rest.split()
        if len(parts) == 2 and parts[1] == "kB":
            out[key.strip()] = int(parts[0]) / 1024
    return out


def pss_mb(pid: int) -> float:
    """The proportional set size of one process, in MiB (0 when it cannot be read)."""
    return _rollup(pid).get("Pss", 0.0)


def memory_mb(pid: int) -> dict[str, float]:
    """``{"rss", "pss", "pss_anon", "pss_file", "uss"}`` of one process in MiB; ``uss`` is what
    only this process maps (private pages), the memory its end would free."""
    r = _rollup(pid)
    return {"rss": r.get("Rss", 0.0), "pss": r.get("Pss", 0.0), "pss_anon": r.get("Pss_Anon", 0.0),
            "pss_file": r.get("Pss_File", 0.0), "uss": r.get("Private_Clean", 0.0) + r.get("Private_Dirty", 0.0)}


def children(pid: int) -> list[int]:
    """The process ids whose parent is ``pid`` (every thread's children)."""
    out: list[int] = []
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return out
    for tid in tids:
        try:
            out.extend(int(c) for c in Path(f"/proc/{pid}/task/{tid}/children").read_text().split())
        except OSError:
            continue
    return out


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it, parents before their children."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop(0)
        out.append(p)
        todo.extend(c for c in children(p) if c not in out)
    return out


def tree_pss_mb(pid: int) -> float:
    """The PSS of ``pid`` and every process below it, in MiB: the memory the tree holds."""
    return sum(pss_mb(p) for p in descendants(pid))


def cpu_seconds(pid: int) -> float:
    """The CPU time (user and system) a process has used so far, in seconds (0 when it cannot be read)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0
