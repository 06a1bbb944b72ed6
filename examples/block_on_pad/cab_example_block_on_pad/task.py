"""block_on_pad: put the red block on the green pad.

Scene (per seed)
    The task kit's table and wall (``cab_core.kits.scene.base_scene``). A red 4 cm cube (0.05 kg) lies on the table at x in +-[0.08, 0.25],
    y in [-0.2, 0.0], any heading; a thin green pad (10 x 10 cm, 5 mm thick, static) lies on the
    same side, its centre 0.12 m to 0.25 m from the cube's.

Success (final state)
    ``on_pad``: the cube's centre is within 0.04 m of the pad's centre in x and in y (its
    footprint on the pad) and 2 cm +- 1 cm above the pad's top (resting on it, not held above);
    ``gripper_open``: the gripper of the arm on the cube's side is open (command > 0.8).
    Guard: the cube stays on the table (not below the table top - 0.08 m).

Checkpoints
    Subgoals: (1) the cube lifted 3 cm off the table; (2) the cube resting on the pad.
    Spatial: "Grasp block" (the TCP within 2 cm of the grasp point), "Place on pad" (the TCP within
    4 cm (xy) over the pad's centre, -2 cm to +5 cm about the release height), after the first.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, sphere
from cab_core.contracts.scene import Body, Box, Material, Shape
from cab_core.contracts.task import SceneInstance, TaskInfo, ToolCaller, rng_for
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView
from cab_core.kits.margins import margin_above, margin_within
from cab_core.kits.oracle import Hands, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, base_scene, pose_list, rand_pose, sample_until, table_top_z
from cab_core.kits.task import SceneTask

NAME = "block_on_pad"
HALF = 0.02  # the cube's half size
PAD_HALF = (0.05, 0.05, 0.0025)
XY_TOL = 0.04
Z_TOL = 0.01
GRIPPER_OPEN = 0.8
LIFTED = 0.03

INFO = TaskInfo(
    name=NAME,
    instruction="Pick up the red block and put it on the green pad, then let go.",
    seed=0,
    scoring="final",
    budget_tool_calls=30,
    budget_sim_s=40.0,
    category="Example (third-party plugin)",
    reference_solution_api_calls=12,
    reference_solution_sim_s=10.0,
    subgoals=("Block lifted off the table.", "Block resting on the pad."),
    spatial_checkpoints=(
        {"name": "Grasp block", "arm": "Either", "condition_cm": "$d_3\\leq 2$.", "prerequisite": "--"},
        {"name": "Place on pad", "arm": "Either", "condition_cm": "$d_{xy}\\leq 4$, $\\Delta z\\in[-2,5]$.",
         "prerequisite": "1"},
    ),
)


class BlockOnPadVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.pad = np.asarray(info["pad"]["pose"][:3], float)
        self.rest_z = self.pad[2] + PAD_HALF[2] + HALF  # the cube's centre resting on the pad
        self.arm = info["side_arm"]
        self.guarded_objects = ("block",)  # the core's guard: off the table below guard_min_z
        self.guard_min_z = table_top_z() - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        p = np.asarray(w.pose("block")[:3], float)
        d = np.array([p[0] - self.pad[0], p[1] - self.pad[1], p[2] - self.rest_z])
        tol = np.array([XY_TOL, XY_TOL, Z_TOL])
        grip = w.gripper_command(self.arm)
        on_pad = bool(np.all(np.abs(d) < tol))
        return Evaluation(
            success=on_pad and grip > GRIPPER_OPEN,
            predicates={"on_pad": on_pad, "gripper_open": bool(grip > GRIPPER_OPEN)},
            values={"block_dx": float(d[0]), "block_dy": float(d[1]), "block_dz": float(d[2]),
                    "gripper": float(grip)},
            margins={"on_pad": margin_within(d, tol, "m"),
                     "gripper_open": margin_above(grip, GRIPPER_OPEN, "gripper command")},
        )


class BlockOnPad(SceneTask):
    """Declares its own metadata (``INFO``, which names it): the core learns about the task only from
    this plugin."""

    info = INFO
    seed_sets = {"heldout": tuple(range(100, 110))}

    def build(self, seed: int, embodiment: Any = None) -> SceneInstance:
        rng = rng_for(seed, self.name)
        top = table_top_z()
        cube = sample_until(lambda: rand_pose(rng, (-0.25, 0.25), (-0.2, 0.0), (top + HALF,), rotate_rand=True,
                                              rotate_lim=(0.0, 0.0, np.pi / 2)),
                            lambda p: abs(p[0]) >= 0.08, what="the block")
        side = -1.0 if cube[0] < 0 else 1.0

        def pad_ok(p: np.ndarray) -> bool:
            return 0.12 <= float(np.hypot(p[0] - cube[0], p[1] - cube[1])) <= 0.25

        pad = sample_until(lambda: rand_pose(rng, sorted((side * 0.06, side * 0.28)), (-0.22, 0.02),
                                             (top + PAD_HALF[2],)),
                           pad_ok, what="the pad")
        scene = base_scene()
        scene.bodies.append(Body("block", [Shape(Box((HALF, HALF, HALF)),
                                                 material=Material(color=(0.8, 0.05, 0.05, 1.0),
                                                                   static_friction=0.8, dynamic_friction=0.7))],
                                 pose=tuple(cube), mass=0.05))
        scene.bodies.append(Body("pad", [Shape(Box(PAD_HALF), material=Material(color=(0.05, 0.6, 0.1, 1.0)))],
                                 pose=tuple(pad), kind="static"))
        arm = "left" if side < 0 else "right"
        tip = 0.035
        arms = getattr(embodiment, "arms", None) or {}
        if arm in arms:  # the robot's declared fingertip offset, not a number of one robot
            tip = float(arms[arm].gripper.tip_ahead_of_tcp_m)
        info = {"task": self.name, "seed": int(seed), "table_top_z": top, "side_arm": arm,
                "block": {"name": "block", "pose": pose_list(cube), "half_size": HALF},
                "pad": {"name": "pad", "pose": pose_list(pad), "half_size": list(PAD_HALF)},
                # the TCP at the grasp: fingertips 5 mm above the table
                "grasp_tcp_above_table": round(tip + 0.005, 6),
                "release_tcp_above_pad": round(tip + 0.005 + 0.004, 6)}
        return SceneInstance(scene=scene, info=info)

    def verifier(self, instance: SceneInstance) -> Verifier:
        return BlockOnPadVerifier(instance.info)

    def subgoals(self, w: WorldView) -> list[bool]:
        v = BlockOnPadVerifier(w.info)
        lifted = float(w.pose("block")[2]) > table_top_z() + HALF + LIFTED
        return [lifted, bool(v.evaluate(w).predicates["on_pad"])]

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        top = float(info["table_top_z"])
        pad = np.asarray(info["pad"]["pose"][:3], float)
        release = pad + [0.0, 0.0, PAD_HALF[2] + float(info["release_tcp_above_pad"])]

        def grasp(w: WorldView) -> np.ndarray:
            p = np.asarray(w.pose("block")[:3], float)
            return np.array([p[0], p[1], top + float(info["grasp_tcp_above_table"])])

        return [SpatialRule("Grasp block", "either", grasp, sphere(2)),
                SpatialRule("Place on pad", "either", lambda w: release, box(dx=4, dy=4, dz=(-2, 5)), (0,))]

    def oracle(self, call: ToolCaller, world: WorldView) -> None:
        """The arm on the block's side picks it from above (fingers across its faces) and sets it
        down on the pad's centre, lets go and rises."""
        info = world.info
        hands = Hands(call, info["side_arm"])
        top = float(info["table_top_z"])
        block = np.asarray(world.pose("block"), float)
        yaw = 2.0 * np.arctan2(block[6], block[3])  # the cube turns about z only
        opening = [float(np.cos(yaw)), float(np.sin(yaw)), 0.0]
        q = top_down_quat(opening)
        hands.grip(1.0)
        hands.pick_held(world, "block",
                        lambda pose: ([pose[0], pose[1], top + float(info["grasp_tcp_above_table"])], q),
                        lift=0.10)
        pad = np.asarray(info["pad"]["pose"][:3], float)
        hands.place([pad[0], pad[1], pad[2] + PAD_HALF[2] + float(info["release_tcp_above_pad"])], q)
        call("done", report="put the red block on the green pad and let go", success_claim=True)


TASK = BlockOnPad
