"""From a composed config to a finished, recorded attempt. An attempt interrupted while the agent
plays (Ctrl-C, SIGTERM) is recorded as ``interrupted`` (never scored) before the interruption goes on."""
from __future__ import annotations

import logging

from cab_core.attempt.engine import cpu_slots
from cab_core.attempt.engine.episode import Episode
from cab_core.attempt.engine.faults import INTERRUPTED, is_infrastructure_fault
from cab_core.attempt.spec import AttemptSpec, attempt_spec  # noqa: F401  (attempt_spec: a composed config's spec)
from cab_core.errors import ConfigError
from cab_core.plugins import all_tasks, create, select_record_observers

log = logging.getLogger("cab")


def run_attempt(spec: AttemptSpec) -> dict:
    """Build everything through the plugin registry, run the harness, score, record."""
    tasks = all_tasks()
    if spec.task not in tasks:
        raise ConfigError(f"unknown task {spec.task!r}; choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    observers = select_record_observers(spec.record)  # an unknown name is refused before anything starts
    harness = create("harnesses", spec.harness, {**spec.harness_cfg, "name": spec.harness})
    preflight = getattr(harness, "preflight", None)
    if preflight is not None:  # credentials and endpoints are checked before any simulator starts
        preflight(spec.model_cfg)
    before_build = getattr(harness, "before_build", None)
    if before_build is not None:  # e.g. a server that answers its client while the world is built
        before_build(spec)
    try:
        with cpu_slots.held():  # in a sweep: at most one world built per core at a time (staggered start-ups)
            episode = Episode.open(spec, observers)
    except BaseException:
        close = getattr(harness, "close", None)
        if close is not None:
            close()
        raise
    try:
        try:
            harness.run(episode, spec.model_cfg)
        except Exception as e:  # the fault rule (cab_core.attempt.engine.faults): only a broken host is not scored
            log.exception("harness failed")
            episode.end("host_fault" if is_infrastructure_fault(e) else "harness_error", f"harness: {e!r}")
        except KeyboardInterrupt as e:  # Ctrl-C, or a SIGTERM the program turned into one: never scored
            episode.end(INTERRUPTED, interrupted_detail(e))
            episode.finish()  # the record says so (verdict.excluded), then the interruption goes on up
            raise
        with cpu_slots.held():  # scoring and the video
            return episode.finish()
    finally:
        episode.close()


def interrupted_detail(e: KeyboardInterrupt) -> str:
    """The termination detail of an interrupted attempt: which signal stopped it (a SIGTERM handler
    raises ``KeyboardInterrupt("SIGTERM")``)."""
    how = str(e.args[0]) if e.args else "SIGINT (Ctrl-C)"
    return f"stopped by {how} while the agent played; not scored"
