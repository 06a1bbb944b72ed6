"""A small sweep of real attempts shared by the report, viewer and replay tests.

``build_sweep(root)`` runs oracle, idle and scripted agents on two tasks with ``run_attempt`` into
the first sweep layout ``task/model/seed-S/attempt-A`` (what ``cab -m`` wrote before the simulator
folder; the report tests thus check that ``cab-report`` still reads it), once per test session:
the directory is reused when its ``.complete`` marker exists. The scripted agent exercises what the
oracle and idle agents never do: a planner refusal, a program that raises, a program that moves,
an over-claim, and (on the second task) an attempt that ends without ``done``. On the first task it
also reaches the hammer's grasp region first, and leaves without grasping: arrival without object
control.
"""
from __future__ import annotations

import json
from pathlib import Path

from hydra import compose, initialize_config_module

from cab_core.apps.cli import normalise_overrides
from cab_core.attempt.runner import attempt_spec, run_attempt

TASKS = ("beat_block_hammer", "stack_blocks_three")
PLAN = (("oracle", (1, 2)), ("idle", (1, 2)), ("scripted", (1,)))

RAISING_PROGRAM = "p = get_arm_pose(arm='left')\nraise ValueError('no block found')\n"
MOVING_PROGRAM = ("p = get_arm_pose(arm='right')\n"
                  "r = move_delta(arm='right', dx=0.0, dy=0.0, dz=-0.05)\n"
                  "result = r['status']\n")


# beat_block_hammer: above the hammer's handle, top-down, then down to it (the oracle's approach)
HAMMER_APPROACH = [
    {"tool": "reach_tcp", "args": {"arm": "left", "target_xyz": [-0.05, -0.06, 0.94],
                                   "target_quat": [0.7071068, 0.0, 0.7071068, 0.0]}},
    {"tool": "move_delta", "args": {"arm": "left", "dx": 0.0, "dy": 0.0, "dz": -0.16}},
]


def scripted_calls(first_task: bool) -> list[dict]:
    """The scripted agent's calls: look, (approach the hammer,) an unreachable target, two
    programs, and done on the first task only."""
    calls = [
        {"tool": "capture_head", "args": {}},
        *(HAMMER_APPROACH if first_task else []),
        {"tool": "reach_tcp", "args": {"arm": "left", "target_xyz": [0.0, 0.7, 1.45]}},
        {"tool": "run_code", "args": {"code": RAISING_PROGRAM}},
        {"tool": "run_code", "args": {"code": MOVING_PROGRAM}},
    ]
    if first_task:
        calls.append({"tool": "done", "args": {"report": "moved the right arm down", "success_claim": True}})
    return calls


def attempt_dir(root: Path, task: str, model: str, attempt: int, seed: int = 0) -> Path:
    return Path(root) / task / model / f"seed-{seed}" / f"attempt-{attempt}"


def run_one(out: Path, task: str, model: str, attempt: int, *extra: str) -> dict:
    overrides = [f"task={task}", f"model={model}", f"attempt={attempt}", "seed=0", *extra]
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(overrides))
    return run_attempt(attempt_spec(cfg, out))


def build_sweep(root: Path) -> Path:
    """Run every attempt of PLAN x TASKS under ``root`` (skipped when already complete)."""
    root = Path(root)
    if (root / ".complete").exists():
        return root
    root.mkdir(parents=True, exist_ok=True)
    for i, task in enumerate(TASKS):
        for model, attempts in PLAN:
            for a in attempts:
                out = attempt_dir(root, task, model, a)
                if (out / "result.json").exists():
                    continue
                extra: list[str] = ["record.video_every_steps=50"]
                if model == "scripted":
                    script = root / f"script-{task}.json"
                    script.write_text(json.dumps(scripted_calls(first_task=(i == 0))))
                    extra.append(f"model.script={script}")
                run_one(out, task, model, a, *extra)
    (root / ".complete").write_text("")
    return root


def shared_sweep(tmp_path_factory) -> Path:
    """The session's sweep (built by the first test module that asks for it)."""
    return build_sweep(tmp_path_factory.getbasetemp() / "cab-sweep")


def results(root: Path) -> list[dict]:
    """Every result.json of the sweep, read directly (the tests' independent source of truth)."""
    return [json.loads(p.read_text()) for p in sorted(Path(root).glob("*/*/seed-*/attempt-*/result.json"))]


def events(attempt: Path) -> list[dict]:
    return [json.loads(line) for line in (Path(attempt) / "events.jsonl").read_text().splitlines() if line.strip()]


if __name__ == "__main__":  # build a sweep by hand: python tests/attempt_records.py <dir>
    import sys

    print(build_sweep(Path(sys.argv[1])))
