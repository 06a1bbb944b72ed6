"""put_bottles_dustbin: put the three bottles into the dustbin left of the table.

Description
    The table is shifted 0.3 m to the robot's right; in the space this leaves on the left stands a
    tall open dustbin (a green pedal bin, 0.34 x 0.50 m, rim at 0.62 m, the bucket's floor at 0.20 m),
    its rim below the table top. Three plastic drink bottles (17.5-20.5 cm tall, about 6 cm across,
    50-60 g: blue-capped water, a green contoured soda, an orange juice) stand upright on the table.
    The robot must pick up each bottle and drop it into the dustbin.

Randomisation (per seed; FACTS B.6)
    The bottle models are fixed (upstream's ``114_bottle`` ids 1, 2, 3) and so is the dustbin
    (``011_dustbin`` id 0, static, at (-0.45, 0, 0)). Each bottle is drawn with ``rand_pose`` at
    x in [-0.25, 0.3] with |x| >= 0.05, y in [0.03, 0.23], redrawn until it is >= 0.13 m from the
    bottles drawn before it; no rotation (upright; the turn about the axis is 0). The bottles stand
    on the table top (z 0.74).

Success (final state; RoboTwin's check)
    Every bottle (its pose: the centre of the bottle) lies in the dustbin's region:
    |x + 0.45| < 0.221, |y| < 0.325 and 0.2 < z < 0.7 (``bottle1_in_bin``, ``bottle2_in_bin``,
    ``bottle3_in_bin``). With this dustbin the region is its inside: a bottle resting on the
    bucket's floor has its centre at >= 0.22 m, one left on the table at >= 0.82 m.
    Guard (the card's destructive check): a bottle below z = 0.1 m (on the floor) or outside
    x in [-0.85, 0.55], y in [-0.55, 0.55] fails the attempt.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, cylinder
from cab_core.contracts.scene import SceneSpec
from cab_core.contracts.verifier import Evaluation, Margin, Verifier, WorldView
from cab_core.geometry import transform_point
from cab_core.kits.margins import margin_above, margin_all, margin_below, margin_within
from cab_core.kits.oracle import OPEN, TOLERANT, Hands, OracleFailed, tcp_quat, world_point
from cab_core.kits.scene import pose_list, rand_pose, sample_until

from ..assets_bins import DRINK_BOTTLES, big_dustbin, big_dustbin_info, bottle_body, bottle_info
from ..common import CodeActionTask

TABLE_X = 0.3
DUSTBIN_POSE = (-0.45, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
BOTTLE_IDS = (1, 2, 3)
KEYS = ("bottle1", "bottle2", "bottle3")
REGION_CENTER = (-0.45, 0.0)
REGION_HALF = (0.221, 0.325)
REGION_Z = (0.2, 0.7)
FLOOR_BAND = 0.02  # a bottle lying on the bucket's floor has its centre at least this far above REGION_Z[0]
MIN_PAIR_DIST = 0.13
GUARD_MIN_Z = 0.1
GUARD_XY = ((-0.85, 0.55), (-0.55, 0.55))
APPROACH_YAW = 0.8  # rad right of straight ahead: the approach comes from the front-left
APPROACH = np.array([np.sin(APPROACH_YAW), np.cos(APPROACH_YAW), 0.0])
GRASP_SHORT = 0.01  # TCP this far short of the bottle's axis
PRE_GRASP = 0.10
LIFT = 0.10
DROP_CLEARANCE = 0.06  # the held bottle's base above the dustbin's rim when let go
DROP_Y = (-0.10, 0.0, 0.10)  # where along the dustbin the three bottles are let go
HAND_CLEAR = 0.07  # the empty hand's TCP this far above the standing bottles' tops (its lowest
# part, the gripper housing, 3 cm below the TCP)
CARRY_CLEAR = 0.05  # the held bottle's base this far above the standing bottles' tops while carried
PICK_TRIES = 2
POISED = 0.015  # an open TCP this close to a bottle's grasp is about to close on it


class PutBottlesDustbinVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.names = [info[k]["name"] for k in info["bottles"]]
        self.keys = list(info["bottles"])
        r = info["region"]
        self.center = np.asarray(r["center_xy"], float)
        self.half = np.asarray(r["half_xy"], float)
        self.z = tuple(r["z_range"])
        g = info["guard"]
        self.guarded_objects = tuple(self.names)
        self.guard_min_z = float(g["min_z"])
        self.guard_xy = (tuple(g["x"]), tuple(g["y"]))

    def in_region(self, p) -> bool:
        d = np.abs(np.asarray(p[:2]) - self.center)
        return bool(d[0] < self.half[0] and d[1] < self.half[1] and self.z[0] < p[2] < self.z[1])

    def region_margin(self, p) -> Margin:
        """The margin of ``in_region``: x and y against the half-sizes; z above the range's bottom
        against FLOOR_BAND (a bottle on the bucket's floor cannot sink further: it reads >= 1, never
        borderline), below its top against the range's half-height."""
        return margin_all(margin_within(np.asarray(p[:2]) - self.center, self.half, "m"),
                          margin_above(p[2], self.z[0], "m", FLOOR_BAND),
                          margin_below(p[2], self.z[1], "m", (self.z[1] - self.z[0]) / 2))

    def evaluate(self, w: WorldView) -> Evaluation:
        preds: dict[str, bool] = {}
        values: dict[str, float] = {}
        margins: dict[str, Margin] = {}
        for key, name in zip(self.keys, self.names):
            p = w.pose(name)[:3]
            preds[f"{key}_in_bin"] = self.in_region(p)
            margins[f"{key}_in_bin"] = self.region_margin(p)
            values.update({f"{key}_dx": float(p[0] - self.center[0]), f"{key}_dy": float(p[1] - self.center[1]),
                           f"{key}_z": float(p[2])})
        return Evaluation(success=all(preds.values()), predicates=preds, values=values, margins=margins)

    def guard(self, w: WorldView) -> dict[str, bool]:
        """``<bottle>_on_table``: above the card's min_z and inside its xy bounds."""
        (x0, x1), (y0, y1) = self.guard_xy
        out = {}
        for n in self.guarded_objects:
            p = w.pose(n)
            out[f"{n}_on_table"] = bool(p[2] >= self.guard_min_z and x0 <= p[0] <= x1 and y0 <= p[1] <= y1)
        return out

    def guard_margins(self, w: WorldView) -> dict[str, Margin]:
        """The margins of this ``guard`` (its xy bounds too), each side against ``guard_scale_m``."""
        (x0, x1), (y0, y1) = self.guard_xy
        s = self.guard_scale_m
        out = {}
        for n in self.guarded_objects:
            p = w.pose(n)
            out[f"{n}_on_table"] = margin_all(margin_above(p[2], self.guard_min_z, "m", s),
                                              margin_above(p[0], x0, "m", s), margin_below(p[0], x1, "m", s),
                                              margin_above(p[1], y0, "m", s), margin_below(p[1], y1, "m", s))
        return out


class PutBottlesDustbin(CodeActionTask):
    table_x = TABLE_X
    verifier_class = PutBottlesDustbinVerifier

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        scene.bodies.append(big_dustbin("dustbin", DUSTBIN_POSE))
        info: dict[str, Any] = {
            "table_x": TABLE_X,
            "table_x_range": [TABLE_X - 0.6, TABLE_X + 0.6],
            "dustbin": big_dustbin_info(DUSTBIN_POSE),
            "region": {"center_xy": list(REGION_CENTER), "half_xy": list(REGION_HALF), "z_range": list(REGION_Z)},
            "guard": {"min_z": GUARD_MIN_Z, "x": list(GUARD_XY[0]), "y": list(GUARD_XY[1])},
            "bottles": list(KEYS),
        }
        drawn: list[np.ndarray] = []
        for key, model_id in zip(KEYS, BOTTLE_IDS):
            style = DRINK_BOTTLES[model_id]
            pose = sample_until(
                lambda style=style: rand_pose(rng, (-0.25, 0.3), (0.03, 0.23), (top + style.height / 2 + 0.001,)),
                lambda p: abs(p[0]) >= 0.05 and all(np.hypot(*(p[:2] - q[:2])) >= MIN_PAIR_DIST for q in drawn),
                what=f"{key}")
            drawn.append(pose)
            scene.bodies.append(bottle_body(key, style, f"bottle114-{model_id}", pose))
            b = bottle_info(style, model_id, "114_bottle")
            b.update(name=key, pose=pose_list(pose))
            info[key] = b
        info["grasp_short_m"] = GRASP_SHORT
        info["drop_tcp"] = pose_list(_drop_tcp(info, info["bottle1"]))  # the reference solution's release point
        return info

    # -- analysis -------------------------------------------------------------------------------
    def subgoals(self, w: WorldView) -> list[bool]:
        p = self.evaluate(w).predicates
        each = [p[f"{k}_in_bin"] for k in w.info["bottles"]]
        return each + [all(each)]

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        def grasp_ref(key: str):
            b = info[key]
            return lambda w: _grasp_tcp(w.pose(b["name"]), b)

        drop = info["drop_tcp"]
        rules = [SpatialRule(f"Approach bottle {i}", "either", grasp_ref(k), cylinder(4, (-8, 6)))
                 for i, k in enumerate(info["bottles"])]
        # "prerequisite: 1 or 2 or 3": an approach of any bottle
        rules.append(SpatialRule("Drop over bin", "either", lambda w: drop, box(22.0, 32.4, 8),
                                 prerequisites=(0, 1, 2), any_prerequisite=True))
        return rules

    # -- reference solution ---------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The left arm does all three bottles, the one nearest along the approach first. The
        approach comes from the front-left (0.8 rad right of straight ahead) and the open hand
        sweeps a band 17 cm wide (the finger rail) from 20 cm behind the bottle: taken in this order,
        every bottle still standing is ahead of the one being taken, never in that band (by x, a
        bottle standing just in front of the one taken, the pair's 13 cm apart, was hit). Each pick:
        above the approach's start, high enough to pass over every standing bottle, straight down,
        in, a side grasp of the body, a lift until the held bottle's base clears every standing
        bottle's top (it may now be carried over them), a check that every finger touches it (else
        it is grasped again), across to above the dustbin at that height, down until its base is 6
        cm above the rim (the three at different places along y), let go, and straight up to
        above the bottles again. The right arm first moves out of the left arm's way when a bottle
        stands on its side (28 calls)."""
        info = world.info
        q = tcp_quat(APPROACH, (-APPROACH[1], APPROACH[0], 0.0))  # the gripper's z axis up
        # from a later stage (a fork): the bottles already in the dustbin stay there; the drop
        # places along the dustbin go on from their count
        verifier = self.verifier_class(info)
        left = [k for k in info["bottles"] if not verifier.in_region(world.pose(info[k]["name"])[:3])]
        # (the right arm steps aside once: not again when it is away from its start already)
        right_home = (world.start or {}).get("tcp", {}).get("right")
        right_away = right_home is not None and world.tcp_pose("right")[0] - right_home[0] > 0.10
        if any(world.pose(info[k]["name"])[0] > 0.05 for k in left) and not right_away:
            Hands(call, "right").move(dx=0.15, dy=-0.05, dz=0.05, what="right arm aside", ok=TOLERANT)
        hands = Hands(call, "left")
        for i in range(len(info["bottles"]) - len(left), len(info["bottles"])):
            # a bottle the hand holds, or is open around (``keeps_hands``), is the one it goes on with
            held_key = next((k for k in left if world.gripper_holds("left", info[k]["name"])), None)
            poised_key = next((k for k in left if _poised(world, info[k], q)), None) if held_key is None else None
            key = held_key or poised_key or min(left, key=lambda k: float(world.pose(info[k]["name"])[:2] @ APPROACH[:2]))
            b = info[key]
            name = b["name"]
            hover_z = _tops(world, info, left) + HAND_CLEAR
            left.remove(key)
            carry_top = _tops(world, info, left) + CARRY_CLEAR  # what the held bottle must pass over
            if held_key is not None:
                base = _base_z(world, b)
                over_bin = np.all(np.abs(world.pose(name)[:2] - verifier.center) < verifier.half)
                if not over_bin and base < carry_top:
                    hands.move(dz=max(LIFT, carry_top - base), what="lift", ok=TOLERANT)
            else:
                for t in range(PICK_TRIES):
                    if not (t == 0 and poised_key is not None):
                        g = _grasp_tcp(world.pose(name), b)
                        pre = g - PRE_GRASP * APPROACH
                        hands.reach([pre[0], pre[1], max(pre[2], hover_z)], q, "above the approach to the bottle")
                        hands.move_to_height(world, pre[2], "down before the bottle")
                        g = _grasp_tcp(world.pose(name), b)  # where it stands now
                        hands.move_to(world, g, "around the bottle")
                    hands.grip(0.0)
                    base = _base_z(world, b)
                    hands.move(dz=max(LIFT, carry_top - base), what="lift", ok=TOLERANT)
                    if world.gripper_holds("left", name):
                        break
                    # not held: open, back out along the approach and up, and take it again
                    hands.grip(1.0)
                    hands.move(*(-PRE_GRASP * APPROACH), what="back out", ok=TOLERANT)
                else:
                    raise OracleFailed(f"{name}: not held after {PICK_TRIES} grasps")
            tcp = world.tcp_pose("left")[:3]
            held = world.pose(name)[:3] - tcp
            drop = _drop_tcp(info, b, held, DROP_Y[i])
            hands.reach([drop[0], drop[1], max(drop[2], float(tcp[2]))], None, "above the dustbin")
            hands.move_to_height(world, drop[2], "down over the dustbin", ok=TOLERANT)
            hands.grip(1.0)
            # straight up, over the standing bottles' tops, before the next one (the hand is below the
            # table top here)
            up = _tops(world, info, left) + HAND_CLEAR if left else world.tcp_pose("left")[2] + 0.15
            hands.move(dz=max(0.15, up - world.tcp_pose("left")[2]), what="rise", ok=TOLERANT)
        call("done", report="dropped the three bottles into the dustbin", success_claim=True)

    def keeps_hands(self, world: WorldView) -> bool:
        """Whether the left hand holds a bottle or is open around one, ready to close: then the
        solution goes on from there."""
        info = world.info
        q = tcp_quat(APPROACH, (-APPROACH[1], APPROACH[0], 0.0))
        return any(world.gripper_holds("left", info[k]["name"]) or _poised(world, info[k], q) for k in info["bottles"])


def _poised(world: WorldView, b: dict, q) -> bool:
    """Whether the left hand is open around bottle ``b`` at its grasp, turned as the solution
    turns it (a grasp under way)."""
    tcp = world.tcp_pose("left")
    return bool(world.gripper_command("left") >= OPEN and abs(float(np.dot(tcp[3:], q))) > 0.995
                and np.linalg.norm(tcp[:3] - _grasp_tcp(world.pose(b["name"]), b)) < POISED)


def _tops(world: WorldView, info: dict, keys) -> float:
    """The highest top of the bottles ``keys`` as they stand (the table top if none)."""
    tops = [float(world.pose(info[k]["name"])[2]) + info[k]["height"] / 2 for k in keys]
    return max(tops, default=float(info["table_top_z"]))


def _base_z(world: WorldView, b: dict) -> float:
    """The lowest point of a bottle's base circle (it may lean)."""
    p = world.pose(b["name"])
    r, h = b["body_radius"], b["height"]
    return float(min(transform_point(p, (r * np.cos(t), r * np.sin(t), -h / 2))[2]
                     for t in np.linspace(0, 2 * np.pi, 12, endpoint=False)))


def _grasp_tcp(pose, b: dict) -> np.ndarray:
    """Where the TCP closes on a standing bottle: its grasp point, GRASP_SHORT back along the
    reference solution's approach."""
    return world_point(pose, b["grasp_point"]) - GRASP_SHORT * APPROACH


def _drop_tcp(info: dict, b: dict, held=None, dy: float = 0.0) -> np.ndarray:
    """TCP over the middle of the dustbin (shifted ``dy`` along y) with the held bottle's base
    DROP_CLEARANCE above the rim. ``held``: the bottle centre relative to the TCP (default: upright,
    grasped as planned)."""
    d = info["dustbin"]
    if held is None:
        held = np.asarray(b["functional_point"]) - np.asarray(b["grasp_point"]) + GRASP_SHORT * APPROACH
    centre = np.array([d["opening_center"][0], d["opening_center"][1] + dy,
                       d["rim_z"] + DROP_CLEARANCE + b["height"] / 2])
    return centre - np.asarray(held, float)


TASK = PutBottlesDustbin
