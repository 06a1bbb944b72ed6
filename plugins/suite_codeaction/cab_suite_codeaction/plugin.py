"""Entry point of the CodeActionBench suite (group ``cab``, name ``suite_codeaction``)."""
from __future__ import annotations

from cab_core.contracts.hookspecs import hookimpl

from .tasks import load_tasks


@hookimpl
def cab_task_suites():
    return {"codeaction": load_tasks}


@hookimpl
def cab_published_figures():
    from .paper_figures import published_figures

    return {"paper": published_figures}
