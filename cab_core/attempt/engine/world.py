"""Building the world of one attempt: the task's instance at the attempt's seed (perturbed when the
spec asks), the simulator built from it, the planner set up, the robot at home, the scene settled
(uncharged, before the agent starts); and reading its privileged state (snapshots for the record,
never for the agent)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from cab_core.attempt.variation.perturb import Perturbation, perturb_scene
from cab_core.attempt.variation.randomize import Randomization, randomize_instance
from cab_core.contracts.scene import CameraSpec
from cab_core.errors import ConfigError
from cab_core.plugins import all_tasks, create

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.attempt.spec import AttemptSpec
    from cab_core.contracts.task import SceneInstance, Task
    from cab_core.tools.context import RobotContext

RECORD_CAMERA = "record_camera"  # the camera of the attempt's video: the head camera's pose and view


class BuiltWorld:
    """The simulator, planner and embodiment of one attempt, built and settled.

    ``instance``: the task's scene instance (its ``info`` is privileged); ``perturbation``: what
    ``spec.perturb`` drew (None: the instance as sampled). ``video_size``: (w, h) adds the record
    camera (the head camera's pose and field of view) to the scene; None: no video."""

    def __init__(self, spec: AttemptSpec, task: Task, sim, planner, embodiment,
                 video_size: tuple[int, int] | None = None):
        self.spec, self.task, self.sim, self.planner, self.emb = spec, task, sim, planner, embodiment
        self.instance: SceneInstance = task.build(spec.seed, embodiment)
        scene = self.instance.scene
        self.perturbation: dict | None = None
        if spec.perturb is not None:
            p = Perturbation(**spec.perturb)
            self.perturbation = {**p.as_record(), "objects": perturb_scene(scene, p, spec.seed)}
        self.randomization: dict | None = None
        built_emb = embodiment  # what the simulator builds: its fixed cameras jittered by randomisation
        if spec.randomize:
            r = Randomization(**spec.randomize)
            built_emb, self.randomization = randomize_instance(
                scene, embodiment, r, spec.seed, spec.task, task.info.instruction,
                task.distractor_slots(self.instance) if "distractors" in r.parts else [])
        if video_size is not None:
            head = next(c for c in built_emb.cameras if c.name == "head_camera")
            scene.cameras.append(CameraSpec(RECORD_CAMERA, int(video_size[0]), int(video_size[1]),
                                            head.fovy_deg, head.pose))
        sim.build(scene, built_emb)
        planner.setup(embodiment, sim.timestep)
        sim.set_qpos(np.asarray(self.home_qpos(), float))
        sim.step(task.settle_steps())  # uncharged settling before the agent starts

    def home_qpos(self) -> list[float]:
        """Every arm at its home configuration with its gripper open, in the simulator's joint order."""
        home: list[float] = []
        for arm in sorted(self.emb.arms):
            a = self.emb.arms[arm]
            home += list(a.home_qpos) + [a.gripper.open_target] * len(a.gripper.joints)
        return home

    def scene_info(self) -> dict:
        """The privileged description of the instance (``privileged/scene_info.json``)."""
        return {"task": self.spec.task, "seed": self.spec.seed, "info": self.instance.info,
                "objects": self.sim.object_names(), "perturbation": self.perturbation,
                "randomization": self.randomization}

    def object_states(self) -> dict[str, Any]:
        """Every object's pose (and an articulated object's joint positions and link poses), rounded
        as the record keeps them."""
        sim, objs = self.sim, {}
        for n in sim.object_names():
            objs[n] = {"pose": np.round(sim.get_object_pose(n), 6).tolist()}
            q = sim.get_object_qpos(n)
            if len(q):
                objs[n]["qpos"] = np.round(q, 6).tolist()
                objs[n]["links"] = {link: np.round(sim.get_object_link_pose(n, link), 6).tolist()
                                    for link in sim.get_object_link_names(n)}
        return objs

    def contacts(self) -> list[list]:
        """The last step's contacts that carried impulse: [a, b, impulse]."""
        return [[c.a, c.b, round(float(c.impulse), 7)] for c in self.sim.get_contacts() if c.impulse > 1e-6]

    def snapshot(self, ctx: RobotContext, physics_step: int, calls: int = 0, latched: bool = False) -> dict:
        """A privileged snapshot of the world (``privileged/snapshots.jsonl``; never for the agent):
        objects, each arm's TCP, gripper command and finger gap, contacts, the clock."""
        arms = {a: {"tcp_pose": np.round(ctx.tcp_pose(a), 6).tolist(), "gripper_cmd": ctx.gripper_cmd[a],
                    "finger_gap_m": round(ctx.finger_gap(a), 5)} for a in sorted(self.emb.arms)}
        return {"physics_step": physics_step, "tick": ctx.tick, "calls": calls, "objects": self.object_states(),
                "arms": arms, "contacts": self.contacts(), "latched": bool(latched)}

    @classmethod
    def open(cls, spec: AttemptSpec, video_size: tuple[int, int] | None = None) -> BuiltWorld:
        """The world of ``spec``, its parts created through the plugin registry."""
        return with_parts(spec, lambda task, sim, planner, emb: cls(spec, task, sim, planner, emb, video_size))


def create_parts(spec: AttemptSpec) -> tuple:
    """``(task, simulator, planner, embodiment)`` of ``spec``, created through the plugin registry."""
    tasks = all_tasks()
    if spec.task not in tasks:
        raise ConfigError(f"unknown task {spec.task!r}; choices: {', '.join(sorted(tasks)) or '(none installed)'}")
    emb = create("embodiments", spec.embodiment, spec.embodiment_cfg)
    planner = create("planners", spec.planner, spec.planner_cfg)
    sim = create("simulators", spec.sim, spec.sim_cfg)
    return tasks[spec.task], sim, planner, emb


def with_parts(spec: AttemptSpec, make):
    """``make(task, simulator, planner, embodiment)`` on the parts of ``spec`` (:func:`create_parts`);
    the simulator is closed again if ``make`` fails."""
    task, sim, planner, emb = create_parts(spec)
    try:
        return make(task, sim, planner, emb)
    except BaseException:
        close_quietly(sim)
        raise


def close_quietly(sim) -> None:
    try:
        sim.close()
    except Exception:
        pass
