"""The plugin module named by the ``cab`` entry point: what this package adds to cab."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl


def _tasks():
    from .task import TASK

    return {TASK.name: TASK()}


@hookimpl
def cab_task_suites():
    return {"example_block_on_pad": _tasks}


@hookimpl
def cab_record_observers():
    from .observer import TcpCsv

    return {"tcp_csv": TcpCsv}
