"""Entry point of the CodeActionBench suite (group ``cab``, name ``suite_codeaction``)."""
from __future__ import annotations

import cab_core

from .tasks import load_tasks


@cab_core.hookimpl
def cab_task_suites():
    return {"codeaction": load_tasks}
