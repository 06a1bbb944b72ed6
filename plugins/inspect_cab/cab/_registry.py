"""``cab/codeaction`` and its scorer and metrics, as Inspect registers them (the entry point
``inspect_ai: cab``). Thin definitions: the work is in :mod:`inspect_cab`."""
from __future__ import annotations

from collections.abc import Iterable

from inspect_ai import Epochs, Task, task
from inspect_ai.scorer import (
    Metric,
    SampleScore,
    Scorer,
    Target,
    accuracy,
    metric,
    pass_at,
    scorer,
    stderr,
)
from inspect_ai.solver import TaskState
from inspect_cab import scoring
from inspect_cab import task as cab_task
from inspect_cab.offline import use_cab_cache

use_cab_cache()  # mockllm's tokenizer from cab's copy on a machine without internet (inspect_cab.offline)


@metric
def wilson_low() -> Metric:
    """Lower end of the 95% Wilson interval of the success rate."""

    def compute(scores: list[SampleScore]) -> float:
        return scoring.wilson_bounds(scoring.as_floats(scores))[0]

    return compute


@metric
def wilson_high() -> Metric:
    """Upper end of the 95% Wilson interval of the success rate."""

    def compute(scores: list[SampleScore]) -> float:
        return scoring.wilson_bounds(scoring.as_floats(scores))[1]

    return compute


@scorer(metrics=[accuracy(), stderr(), wilson_low(), wilson_high()])
def verdict() -> Scorer:
    """cab's verdict: success from the hidden verifier, read from the attempt's records."""

    async def score(state: TaskState, target: Target):
        return await scoring.score_state(state, target)

    return score


@task
def codeaction(tasks: str | Iterable[str] = "codeaction", sim: str | None = None, seeds: str | int | None = None,
               seed_set: str | None = None, randomize: str | None = None, tool_calls: int | None = None,
               sim_seconds: float | None = None, agent: str = "react", attempts: int = 3,
               records: str | None = None, video: bool = True, cab_args: str | None = None) -> Task:
    """cab's tasks as an Inspect task: one sample per task instance (task, seed), one cab attempt
    per sample and epoch (``attempts`` epochs, the paper's three), scored by cab's verifier.

    Args:
        tasks: task or suite names, comma-separated (a suite stands for its tasks; default: the
            paper's suite, ``codeaction``).
        sim: the simulator (cab's ``sim=``: sapien, mujoco, pybullet; default: cab's default, SAPIEN).
        seeds: seeds, comma-separated; default: each task's catalog seed.
        seed_set: a named seed set of each task instead (e.g. ``heldout``).
        randomize: cab's appearance randomisation (none, lighting, textures, camera, distractors, all).
        tool_calls: tool-call budget per attempt (default: the task's).
        sim_seconds: simulated-seconds budget per attempt (default: the task's).
        agent: ``react`` (Inspect's tool-calling loop) or ``reference`` (cab's reference harness).
        attempts: attempts per instance, as epochs, reduced by mean, pass@1 and pass@k.
        records: folder for the attempt folders (default: ``<log>.cab/`` beside the eval log).
        video: record each attempt's video.
        cab_args: further cab settings for every attempt (space-separated ``key=value``).
    """
    names = cab_task.resolve_tasks(tasks)
    sim = sim or cab_task.default_sim()
    overrides = cab_task.cab_overrides(randomize, tool_calls, sim_seconds, video, cab_args)
    reducers = ["mean", pass_at(1)] + ([pass_at(3)] if attempts >= 3 else [])
    return Task(
        dataset=cab_task.samples(names, sim, seeds, seed_set),
        solver=cab_task.cab_attempt(sim, overrides, agent=agent, records=records),
        scorer=verdict(),
        epochs=Epochs(int(attempts), reducers),
        # agent=reference: Inspect's model bridge serves the harness from the sample's sandbox (this host)
        sandbox="local" if agent == "reference" else None,
    )


def _namespaced(*objects: object) -> None:
    """Inspect namespaces an extension's objects by their top-level package (``cab/...``) only when
    it finds that package installed from site-packages or as an editable install of a distribution
    of the same name; this one is editable in a distribution of another name (cab-inspect), so the
    names are given here as Inspect gives them to an installed package (``inspect eval-set`` and
    ``inspect score`` find the task and scorer again by the names in the log)."""
    from inspect_ai._util.registry import RegistryInfo, registry_add, registry_info

    for o in objects:
        info = registry_info(o)
        if "/" not in info.name:
            registry_add(o, RegistryInfo(type=info.type, name=f"cab/{info.name}", metadata=info.metadata))


_namespaced(codeaction, verdict, wilson_low, wilson_high)
