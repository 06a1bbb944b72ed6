"""stack_blocks_three: stack blue on green on red.

Description
    Three 5 cm cubes, red, green and blue, lie on the table. The robot must stack the green cube on
    the red one and the blue cube on the green one, and let go of them.

Randomisation (per seed; FACTS B.6, RoboTwin's resample-until loops)
    Each cube (half-size 0.025, drawn in the order red, green, blue) with ``rand_pose``:
    x in [-0.28, 0.28], y in [-0.08, 0.05] with ``ylim_prop``, z 0.766, yaw +-0.75 rad, redrawn
    until |x| >= 0.05, its centre is >= 0.15 m from (0, -0.1) (the stacking area stays clear) and
    >= 0.10 m from every cube drawn before it.

Success (final state)
    ``green_on_red``: |green - (red + [0, 0, 0.05])| < [0.025, 0.025, 0.012] per axis;
    ``blue_on_green``: the same for blue over green;
    ``grippers_open``: every arm's commanded gripper value > 0.8.
    The instruction also says "to the center of the table"; the benchmark kept RoboTwin's check,
    which scores only the stack (the paper's alignment appendix lists no change for this task), so
    the stack's distance from the centre is recorded as a value, not scored.
    Guard: no cube may fall off the table.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, sphere
from cab_core.contracts.scene import Body, Box, SceneSpec, Shape
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_within
from cab_core.kits.margins import grippers_open
from cab_core.kits.oracle import Hands, closest_opening, finger_reach, fingers_clear, top_down_quat, yaw_axis
from cab_core.kits.scene import BLUE, DESTRUCTIVE_DROP, GREEN, RED, pose_list, rand_pose, sample_until, yaw_of
from cab_core.kits.task import arm_names

from ..common import CodeActionTask

BLOCK_HALF = 0.025
BLOCK_DENSITY = 600.0  # kg/m^3, a wooden toy block: 0.075 kg
SPAWN_Z = 0.741 + BLOCK_HALF  # 0.766: 1 mm above the table, settles at reset
CLEAR_CENTRE = (0.0, -0.1)
CLEAR_RADIUS = 0.15
MIN_PAIR_DIST = 0.10
TOLERANCE = (0.025, 0.025, 0.012)
GRIPPER_OPEN = 0.8
PARK_X = 0.28  # reference solution: |x| an arm's TCP withdraws to after its placement
GRASP_ABOVE_CENTRE = 0.012  # the expert grasps a cube top-down with the TCP this far above its centre
COLOURS = (("red", RED), ("green", GREEN), ("blue", BLUE))  # bottom -> top of the goal stack
NO_OFFSET = np.zeros(3)  # a checkpoint's reference point exactly at the object (read only)


class StackBlocksThreeVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.order = [info["blocks"][c]["name"] for c in info["stack_order"]]
        self.step = np.array([0.0, 0.0, 2 * float(info["block_half_size"])])
        self.tol = np.asarray(info["tolerance"], dtype=float)
        self.arms = list(info["arms"])
        self.centre = np.asarray(info["stack_target_xy"], dtype=float)
        self.guarded_objects = tuple(self.order)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        p = [np.asarray(w.pose(n)[:3], dtype=float) for n in self.order]
        d1 = p[1] - (p[0] + self.step)
        d2 = p[2] - (p[1] + self.step)
        green_on_red = bool(np.all(np.abs(d1) < self.tol))
        blue_on_green = bool(np.all(np.abs(d2) < self.tol))
        open_, grips, grips_margin = grippers_open(w, self.arms, GRIPPER_OPEN)
        values = {f"green_on_red_d{ax}": float(v) for ax, v in zip("xyz", d1)}
        values.update({f"blue_on_green_d{ax}": float(v) for ax, v in zip("xyz", d2)})
        values.update(grips)
        values["stack_xy_from_centre"] = float(np.linalg.norm(p[0][:2] - self.centre))
        return Evaluation(
            success=green_on_red and blue_on_green and open_,
            predicates={"green_on_red": green_on_red, "blue_on_green": blue_on_green, "grippers_open": open_},
            values=values,
            margins={"green_on_red": margin_within(d1, self.tol, "m"), "blue_on_green": margin_within(d2, self.tol, "m"),
                     "grippers_open": grips_margin},
        )


class StackBlocksThree(CodeActionTask):
    verifier_class = StackBlocksThreeVerifier
    # (1) green aligned above red, (2) blue aligned above green, (3) both together
    subgoal_predicates = (("green_on_red",), ("blue_on_green",), ("green_on_red", "blue_on_green"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        drawn: list[np.ndarray] = []
        blocks: dict[str, dict[str, Any]] = {}
        for colour, material in COLOURS:
            def ok(p: np.ndarray) -> bool:
                return (abs(p[0]) >= 0.05
                        and np.hypot(p[0] - CLEAR_CENTRE[0], p[1] - CLEAR_CENTRE[1]) >= CLEAR_RADIUS
                        and all(np.hypot(*(p[:2] - q[:2])) >= MIN_PAIR_DIST for q in drawn))

            pose = sample_until(
                lambda: rand_pose(rng, (-0.28, 0.28), (-0.08, 0.05), (SPAWN_Z,), ylim_prop=True, rotate_rand=True,
                                  rotate_lim=(0.0, 0.0, 0.75)),
                ok, what=f"the {colour} block")
            drawn.append(pose)
            name = f"{colour}_block"
            scene.bodies.append(Body(name, [Shape(Box((BLOCK_HALF,) * 3), material=material)], pose=tuple(pose),
                                     kind="dynamic", density=BLOCK_DENSITY))
            blocks[colour] = {"name": name, "pose": pose_list(pose), "yaw": round(yaw_of(pose[3:]), 6)}

        info = {
            "block_half_size": BLOCK_HALF,
            "block_size": 2 * BLOCK_HALF,
            "block_mass_kg": round(BLOCK_DENSITY * (2 * BLOCK_HALF) ** 3, 6),
            "blocks": blocks,  # frames: cube centre, axes along the faces
            "stack_order": [c for c, _ in COLOURS],  # bottom -> top
            "tolerance": list(TOLERANCE),
            "gripper_open_threshold": GRIPPER_OPEN,
            "arms": list(arm_names(embodiment)),
            # the cleared area the layout keeps free; where the instruction's "centre" stack can go
            "stack_target_xy": list(CLEAR_CENTRE),
            "resting_center_z": round(top + BLOCK_HALF, 6),
        }
        return info

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Approach each block (the expert's top-down grasp point), then place green on the
        current red and blue on the current green (the TCP where it holds a cube resting there)."""
        order = [info["blocks"][c]["name"] for c in info["stack_order"]]
        lift = np.array([0.0, 0.0, GRASP_ABOVE_CENTRE])
        step = np.array([0.0, 0.0, 2 * float(info["block_half_size"])])

        def at(name, extra=NO_OFFSET):
            return lambda w: np.asarray(w.pose(name)[:3]) + lift + extra

        rules = [SpatialRule(f"Approach block {i + 1}", "either", at(n), sphere(2)) for i, n in enumerate(order)]
        rules.append(SpatialRule("Place green on red", "either", at(order[0], step), box(dx=2.5, dy=2.5, dz=4),
                                 prerequisites=(1,)))
        rules.append(SpatialRule("Place blue on green", "either", at(order[1], step), box(dx=2.5, dy=2.5, dz=4),
                                 prerequisites=(2,)))
        return rules

    def solve(self, call, world: WorldView) -> None:
        """Each cube is picked top-down by the arm on its side (fingers across the two faces needing
        the least wrist roll, or the other two where an open finger would land on another cube;
        aimed again if the arm's way there pushed it, picked again if it is not held) and put on the stack in the
        cleared area in front of the robot, bottom to top. From a later state (a fork) the cubes
        already on the stack, bottom up, are left there (``_levels_done``)."""
        info = world.info
        half = float(info["block_half_size"])
        tx, ty = (float(v) for v in info["stack_target_xy"])
        base_z = float(info["table_top_z"]) + half
        done = self._levels_done(world)
        for level, colour in enumerate(info["stack_order"]):
            if level < done:  # already on the stack (a state a fork starts from)
                continue
            name = info["blocks"][colour]["name"]
            pose = world.pose(name)
            arm = "left" if pose[0] < 0 else "right"
            hands = Hands(call, arm)
            now = world.tcp_pose(arm)

            def aim(p, name=name, now=now):
                # fingers across the faces needing the least wrist roll, unless an open finger would
                # come down on another cube: then across the other two, or whichever is clearer
                faces = [yaw_axis(p[3:], (1, 0, 0)), yaw_axis(p[3:], (0, 1, 0))]
                first = closest_opening(now[3:], faces)
                faces.sort(key=lambda f: -abs(float(np.dot(f, first))))
                others = [(world.pose(o["name"])[:2], half * np.sqrt(2)) for o in info["blocks"].values()
                          if o["name"] != name]
                line = next((f for f in faces if fingers_clear(p[:2], f, 1.0, others)),
                            max(faces, key=lambda f: min(np.linalg.norm(p[:2] + s * finger_reach(1.0) * f[:2] - c)
                                                         - r for s in (-1, 1) for c, r in others)))
                return [p[0], p[1], p[2] + GRASP_ABOVE_CENTRE], top_down_quat(closest_opening(now[3:], [line]))

            hands.pick_held(world, name, aim, lift=0.06 + 2 * half * level)
            # where the held cube sits relative to the TCP decides where the TCP must go
            held = world.pose(name)[:3] - world.tcp_pose(arm)[:3]
            z = base_z + 2 * half * level + 0.004
            if level == 0:
                target = np.array([tx, ty, z])
            else:
                below = world.pose(info["blocks"][info["stack_order"][level - 1]]["name"])[:3]
                target = np.array([below[0], below[1], z])
            hands.place(target - held, None)
            # step aside, well out to the arm's side, so the other arm can reach the stack (its wrist
            # meets a parked arm's otherwise); a planned move where the straight one cannot go
            hands.park(world, -PARK_X if arm == "left" else PARK_X, "clear the stack", planned_rise=0.05)
        call("done", report="stacked blue on green on red", success_claim=True)

    @staticmethod
    def _levels_done(world: WorldView) -> int:
        """How many cubes, bottom up, already stand where the stack needs them and rest there (no
        gripper holds them): the bottom one in the cleared area (or under the next one), each of
        the others on the one below it. 0 at the scene's start (the cleared area is empty)."""
        info = world.info
        names = [info["blocks"][c]["name"] for c in info["stack_order"]]
        half = float(info["block_half_size"])
        tol = np.asarray(info["tolerance"], float)
        base_z = float(info["table_top_z"]) + half

        def free(n: str) -> bool:
            return not any(world.gripper_touches(a, n) for a in info["arms"])

        def on(upper: str, lower: str) -> bool:
            d = world.pose(upper)[:3] - world.pose(lower)[:3] - [0.0, 0.0, 2 * half]
            return bool(np.all(np.abs(d) < tol))

        p0 = world.pose(names[0])[:3]
        base = (np.hypot(*(p0[:2] - np.asarray(info["stack_target_xy"], float))) < 0.02
                and abs(p0[2] - base_z) < 0.01 and free(names[0]))
        done = 0
        if base or on(names[1], names[0]):  # the bottom cube stays where it is
            done = 1
            for k in range(1, len(names)):
                if not (on(names[k], names[k - 1]) and free(names[k])):
                    break
                done = k + 1
        return done


TASK = StackBlocksThree
