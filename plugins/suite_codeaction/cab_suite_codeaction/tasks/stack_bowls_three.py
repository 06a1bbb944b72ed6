"""stack_bowls_three: stack three bowls into one another.

Description
    Three identical small bowls (cream glaze with a blue band under the rim; 11.6 cm across the
    rim, 5 cm tall, 4.5 mm walls flaring out from a 6.4 cm foot, the top 1.5 cm upright) stand
    on the table. The robot must stack them, each one inside the one below, and let go.

Randomisation (per seed; FACTS B.6, RoboTwin's resample-until loops)
    Three bowls (RoboTwin's ``002_bowl`` model 3 for all three, here one generated model) with
    ``rand_pose``: x in [-0.3, 0.3], y in [-0.15, 0.15] with ``ylim_prop``, standing on the table,
    no rotation (they are round); each redrawn until |x| >= 0.09, its centre is >= 0.13 m from
    (0, -0.1) and >= 0.13 m from every bowl drawn before it. The three are then numbered by y
    (bowl1 nearest the robot).

Success (final state)
    Sort the bowls by height (origin z: the centre of the bowl's bottom).
    ``pair_aligned_01`` / ``pair_aligned_12``: consecutive bowls within 0.04 m in x and in y;
    ``heights_ok``: z - [0.74, 0.77, 0.81] < 0.02 for the sorted bowls (one-sided: a bowl nested
    one or two levels up sits 2.1 / 4.2 cm higher here);
    ``grippers_open``: every arm's commanded gripper value > 0.8.
    Guard: no bowl may fall off the table.
"""
from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, annulus
from cab_core.contracts.scene import Body, Material, SceneSpec, Shape, cache_dir
from cab_core.contracts.verifier import Margin, WorldView, margin_all, margin_below, margin_within
from cab_core.geometry import mat_to_quat, quat_to_mat
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until, srgb
from cab_core.kits.task import GrippersOpenVerifier, arm_names

from ..assets_organise import Vessel, revolved, ring_band, tilt_correction, vessel_collision, visual
from ..common import CodeActionTask

BOWL = Vessel(r_bottom=0.032, r_rim=0.058, height=0.05, wall=0.0045, base=0.005, band=0.015)
BOWL_MASS = 0.12  # kg, a small melamine/porcelain rice bowl
BOWL_FRICTION = 0.4  # glazed porcelain (0.45 against the robot's 0.5 finger pads, averaged)
GLAZE = Material(color=srgb(0.93, 0.91, 0.84), roughness=0.3, static_friction=BOWL_FRICTION,
                 dynamic_friction=BOWL_FRICTION)
BAND = Material(color=srgb(0.16, 0.34, 0.70), roughness=0.3)
BOWL_NAMES = ("bowl1", "bowl2", "bowl3")
CLEAR_CENTRE = (0.0, -0.1)
CLEAR_RADIUS = 0.13
MIN_PAIR_DIST = 0.13
XY_TOLERANCE = 0.04
HEIGHT_TARGETS = (0.74, 0.77, 0.81)  # sorted by height, + table z bias
HEIGHT_TOLERANCE = 0.02  # one-sided
GRIPPER_OPEN = 0.8
# the reference grasp: a top-down pinch of the wall at the rim, fingers along the radius, the TCP
# this far above the rim (fingertips 1.5 cm below it), the gripper opened to PINCH_OPEN
PINCH_ABOVE_RIM = 0.022
PINCH_OPEN = 0.4  # pads 2.6 cm apart: clear of the 5 mm wall, fingers reach 4.6 cm from the TCP
RELEASE_PRESS = 0.004  # a carried bowl is lowered this far past its resting height: it sits before the fingers open
HOVER = 0.22
PARK_X = 0.28


@lru_cache(maxsize=4)
def bowl_shapes(cache: str) -> tuple[Shape, ...]:
    """The bowl's shapes (assets written under the cache directory ``cache``)."""
    shapes = vessel_collision("bowl", BOWL, GLAZE)
    shapes.append(visual("bowl-visual", revolved(BOWL.profile()), GLAZE))
    top = BOWL.height - BOWL.wall_horizontal
    shapes.append(visual("bowl-band", ring_band(BOWL.r_outer, top - 0.009, top - 0.004), BAND))
    return tuple(shapes)


def bowl_body(name: str, pose) -> Body:
    return Body(name, list(bowl_shapes(str(cache_dir()))), pose=tuple(pose), kind="dynamic", mass=BOWL_MASS)


def stack_predicates(ps: list[np.ndarray], z_bias: float = 0.0
                     ) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
    """The stack's predicates, the measured values and the predicates' margins."""
    order = sorted(range(len(ps)), key=lambda i: ps[i][2])
    s = [ps[i] for i in order]
    preds = {}
    values = {}
    margins = {}
    for k in range(len(s) - 1):
        d = s[k + 1][:2] - s[k][:2]
        preds[f"pair_aligned_{k}{k + 1}"] = bool(np.all(np.abs(d) < XY_TOLERANCE))
        margins[f"pair_aligned_{k}{k + 1}"] = margin_within(d, XY_TOLERANCE, "m")
        values[f"pair_{k}{k + 1}_dx"], values[f"pair_{k}{k + 1}_dy"] = float(d[0]), float(d[1])
    dz = [float(p[2] - (t + z_bias)) for p, t in zip(s, HEIGHT_TARGETS)]
    preds["heights_ok"] = all(v < HEIGHT_TOLERANCE for v in dz)
    margins["heights_ok"] = margin_all(*(margin_below(v, HEIGHT_TOLERANCE, "m") for v in dz))
    values.update({f"level{k}_dz": v for k, v in enumerate(dz)})
    return preds, values, margins


class StackBowlsThreeVerifier(GrippersOpenVerifier):
    open_threshold = GRIPPER_OPEN

    def __init__(self, info: dict[str, Any]):
        self.names = [b["name"] for b in info["bowls"]]
        self.arms = list(info["arms"])
        self.z_bias = float(info["table_top_z"]) - 0.74
        self.guarded_objects = tuple(self.names)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        return stack_predicates([np.asarray(w.pose(n)[:3], float) for n in self.names], self.z_bias)


class StackBowlsThree(CodeActionTask):
    verifier_class = StackBowlsThreeVerifier

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        drawn: list[np.ndarray] = []
        for i in range(3):
            def ok(p: np.ndarray) -> bool:
                return (abs(p[0]) >= 0.09
                        and np.hypot(p[0] - CLEAR_CENTRE[0], p[1] - CLEAR_CENTRE[1]) >= CLEAR_RADIUS
                        and all(np.hypot(*(p[:2] - q[:2])) >= MIN_PAIR_DIST for q in drawn))

            drawn.append(sample_until(lambda: rand_pose(rng, (-0.3, 0.3), (-0.15, 0.15), (top + 0.0005,),
                                                        ylim_prop=True), ok, what=f"bowl {i + 1}"))
        drawn.sort(key=lambda p: p[1])
        bowls = []
        for name, pose in zip(BOWL_NAMES, drawn):
            scene.bodies.append(bowl_body(name, pose))
            bowls.append({"name": name, "pose": pose_list(pose)})
        grasp_dz = BOWL.height + PINCH_ABOVE_RIM
        info = {
            "bowls": bowls,  # by y, nearest the robot first
            "bowl": {
                "frame": "origin at the centre of the bowl's bottom (on the table when it stands there), +z up "
                         "the axis",
                "rim_outer_radius": BOWL.r_rim,
                "bottom_outer_radius": BOWL.r_bottom,
                "height": BOWL.height,
                "wall_thickness": BOWL.wall,
                "bottom_thickness": BOWL.base,
                "rim_mid_radius": round(BOWL.rim_mid_radius, 6),
                "nest_rise": round(BOWL.nest_rise, 6),  # one bowl in another sits this much higher
                "mass_kg": BOWL_MASS,
                # the reference grasp: TCP over the wall's middle at the rim, this far above the origin
                "grasp_radius": round(BOWL.rim_mid_radius, 6),
                "grasp_tcp_dz": round(grasp_dz, 6),
                "pinch_gripper_command": PINCH_OPEN,
            },
            "xy_tolerance": XY_TOLERANCE,
            "height_targets": [t + top - 0.74 for t in HEIGHT_TARGETS],
            "height_tolerance": HEIGHT_TOLERANCE,
            "gripper_open_threshold": GRIPPER_OPEN,
            "arms": list(arm_names(embodiment)),
            # kept clear by the layout: where the reference solution builds the stack
            "stack_target_xy": list(CLEAR_CENTRE),
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def subgoals(self, w: WorldView) -> list[bool]:
        p = self.evaluate(w).predicates
        return [p["pair_aligned_01"] or p["pair_aligned_12"],
                p["pair_aligned_01"] and p["pair_aligned_12"] and p["heights_ok"]]

    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        """Approaches: the TCP on a ring around the bowl's current axis at the reference pinch
        (radius: the rim's wall middle), at the pinch height. Placements: the same ring around the
        supporting bowl, at the height the pinch has when the moved bowl rests nested in it. The
        reference stacks bowl2 on bowl1 and bowl3 on bowl2 (bowl1, moved first, is the freely
        placed base), so placement k needs the approach of the bowl moved there."""
        b = info["bowl"]
        r_cm = 100.0 * float(b["grasp_radius"])
        names = [x["name"] for x in info["bowls"]]

        def ring(name: str, dz: float):
            return lambda w: np.asarray(w.pose(name)[:3], float) + [0.0, 0.0, dz]

        grasp_dz = float(b["grasp_tcp_dz"])
        nested_dz = grasp_dz + float(b["nest_rise"])
        rules = [SpatialRule(f"Approach bowl {i + 1}", "either", ring(n, grasp_dz), annulus(r_cm, 2.0, 5.0))
                 for i, n in enumerate(names)]
        rules.append(SpatialRule("Two-bowl placement", "either", ring(names[0], nested_dz), annulus(r_cm, 2.0, 5.0),
                                 (1,)))
        rules.append(SpatialRule("Three-bowl placement", "either", ring(names[1], nested_dz),
                                 annulus(r_cm, 2.0, 5.0), (2,)))
        return rules

    # -- reference solution -----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """bowl1 to the cleared spot in front of the robot, bowl2 into it, bowl3 into bowl2. Each
        bowl is pinched top-down at its rim (fingers along the radius, one inside and one outside
        the wall) by the arm on its side, at the rim point facing that arm's shoulder unless a
        finger would then come down on another bowl. It hangs a few degrees tilted from the pinch:
        carried high, the gripper tips back by that much so that it is upright, its axis over the
        support's; lowered until it sits (a bowl let go from above, or tilted, can wedge on the
        rim below), let go, and the arm withdraws to its side. From a later state (a fork): bowls
        already stacked stay (``_bowls_done``), a pinched bowl is carried on (``keeps_hands``), a hand
        still at a rim it let go rises before it steps aside."""
        info = world.info
        b = info["bowl"]
        top = float(info["table_top_z"])
        r_g = float(b["grasp_radius"])
        grasp_dz = float(b["grasp_tcp_dz"])
        rise = float(b["nest_rise"])
        names = [x["name"] for x in info["bowls"]]
        turned: set[str] = set()
        support = None
        for arm in info["arms"]:  # a fork: a hand that just let a bowl go rises and steps aside first
            if self._low_empty_hand(world, arm):
                turned.add(arm)
                hands = Hands(call, arm, hover=HOVER)
                hands.move(dz=0.08, what="retreat", ok=TOLERANT)
                hands.park(world, -PARK_X if arm == "left" else PARK_X, "clear the stack")
        done = self._bowls_done(world)
        for k, name in enumerate(names):
            if k < done:  # already in place (a state a fork starts from)
                support = name
                continue
            c = np.asarray(world.pose(name)[:3], float)
            holder = self._holder(world, name)
            if holder is not None:  # pinched already: go on from the grasp, lifted clear first
                arm = holder
                hands = Hands(call, arm, hover=HOVER)
                turned.add(arm)
                low = c[2] - (top if support is None else float(world.pose(support)[2]) + rise)
                if low < 0.08:
                    hands.move(dz=0.10, what="lift", ok=TOLERANT)
            else:
                arm = "left" if c[0] < 0 else "right"
                hands = Hands(call, arm, hover=HOVER)
                phi = self._pinch_angle(world, name, arm)
                radial = np.array([np.cos(phi), np.sin(phi), 0.0])
                q = top_down_quat(radial)
                if world.gripper_command(arm) != PINCH_OPEN:
                    hands.grip(PINCH_OPEN)
                if arm not in turned:
                    # turn the gripper down where it is, away from the bowls
                    hands.turn_in_place(world, q, rise=0.04, what="turn the gripper down")
                    turned.add(arm)
                grasp = c + r_g * radial + [0.0, 0.0, grasp_dz]
                hands.pick(grasp, q, lift=0.10)
            tcp = world.tcp_pose(arm)
            if abs(quat_to_mat(tcp[3:])[2, 0]) < 0.9:
                raise OracleFailed(f"{name}: the gripper is no longer pointing down")
            # the carried bowl hangs a few degrees tilted from the pinch (set down tilted, it can
            # wedge on the rim below): tip the gripper back by that much so the bowl is upright,
            # its axis on the support's
            pose = world.pose(name)
            fix = tilt_correction(quat_to_mat(pose[3:])[:, 2])
            q_place = mat_to_quat(fix @ quat_to_mat(tcp[3:]))
            if support is None:
                target = np.array([info["stack_target_xy"][0], info["stack_target_xy"][1], top - RELEASE_PRESS])
            else:
                target = np.asarray(world.pose(support)[:3], float) + [0.0, 0.0, rise - RELEASE_PRESS]
            tcp_target = target - fix @ (np.asarray(pose[:3], float) - tcp[:3])
            hands.place(tcp_target, q_place, retreat=0.08, open_to=PINCH_OPEN)
            hands.park(world, -PARK_X if arm == "left" else PARK_X, "clear the stack")
            support = name
        for arm in info["arms"]:
            if world.gripper_command(arm) <= GRIPPER_OPEN:
                Hands(call, arm).grip(1.0)
        call("done", report="stacked the three bowls into one another", success_claim=True)

    @staticmethod
    def _holder(world: WorldView, name: str) -> str | None:
        """The arm whose closed gripper pinches ``name`` (every finger on it), if any."""
        return next((a for a in world.info["arms"]
                     if world.gripper_command(a) < 0.2 and world.gripper_holds(a, name)), None)

    @staticmethod
    def _bowls_done(world: WorldView) -> int:
        """How many bowls, in the order the solution stacks them, already stand where it puts them,
        upright and let go: bowl1 on the table at the stack's spot, each next one nested in the one
        before. 0 at the scene's start (the spot is kept clear)."""
        info = world.info
        names = [x["name"] for x in info["bowls"]]
        top = float(info["table_top_z"])
        rise = float(info["bowl"]["nest_rise"])

        def rests(n: str) -> bool:
            upright = quat_to_mat(world.pose(n)[3:])[2, 2] > 0.98
            return upright and not any(world.gripper_touches(a, n) for a in info["arms"])

        p = [np.asarray(world.pose(n)[:3], float) for n in names]
        spot = np.asarray(info["stack_target_xy"], float)
        if not (np.hypot(*(p[0][:2] - spot)) < 0.03 and abs(p[0][2] - top) < 0.01 and rests(names[0])):
            return 0
        done = 1
        for k in range(1, len(names)):
            d = p[k] - p[k - 1]
            if not (np.hypot(d[0], d[1]) < 0.02 and abs(d[2] - rise) < 0.01 and rests(names[k])):
                break
            done = k + 1
        return done

    @staticmethod
    def _low_empty_hand(world: WorldView, arm: str) -> bool:
        """Whether ``arm``'s open (or pinch-open) gripper, moved from its start, is down at a bowl's
        rim (as after letting it go): opening it wide there and taking it home drags the bowl
        along. Never at the scene's start."""
        if world.start is None or world.gripper_command(arm) < 0.2:
            return False
        tcp = world.tcp_pose(arm)[:3]
        if np.linalg.norm(tcp - world.start["tcp"][arm][:3]) < 0.02:
            return False
        b = world.info["bowl"]
        for x in world.info["bowls"]:
            p = world.pose(x["name"])[:3]
            if (np.hypot(*(tcp[:2] - p[:2])) < float(b["rim_outer_radius"]) + 0.03
                    and tcp[2] < p[2] + float(b["grasp_tcp_dz"]) + 0.06):
                return True
        return False

    def keeps_hands(self, world: WorldView) -> bool:
        """True where a closed gripper pinches a bowl and the other hand holds nothing: the solution
        carries it on (put down where it hangs, over the stack, it can land on a rim and roll off);
        or where a hand that just let a bowl go is still at its rim, the other holding nothing: it
        rises straight up before it steps aside."""
        if world.start is None:
            return False
        arms = list(world.info["arms"])
        names = [x["name"] for x in world.info["bowls"]]
        if any(self._low_empty_hand(world, a) for a in arms):
            return all(world.gripper_command(a) >= 0.2 and not any(world.gripper_holds(a, n) for n in names)
                       for a in arms)
        held = [(a, n) for a in arms for n in names if world.gripper_command(a) < 0.2 and world.gripper_holds(a, n)]
        if len(held) != 1:
            return False
        arm = held[0][0]
        if abs(quat_to_mat(world.tcp_pose(arm)[3:])[2, 0]) < 0.9:  # not pointing down
            return False
        return all(not any(world.gripper_touches(a, n) for n in names) for a in arms if a != arm)

    @staticmethod
    def _pinch_angle(world: WorldView, name: str, arm: str) -> float:
        """The rim angle to pinch: toward the arm's shoulder (about (+-0.27, -0.65)), or the
        nearest angle whose outer finger keeps 2 cm from every other bowl's rim."""
        info = world.info
        c = np.asarray(world.pose(name)[:2], float)
        shoulder = np.array([-0.27 if arm == "left" else 0.27, -0.65])
        d = shoulder - c
        phi0 = float(np.arctan2(d[1], d[0]))
        r_rim = float(info["bowl"]["rim_outer_radius"])
        reach = float(info["bowl"]["grasp_radius"]) + 0.024 + 0.055 * PINCH_OPEN  # outer finger's outer side
        others = [np.asarray(world.pose(o["name"])[:2], float) for o in info["bowls"] if o["name"] != name]
        for step in range(0, 13):
            for sgn in (1, -1):
                phi = phi0 + sgn * step * np.pi / 12
                f = c + reach * np.array([np.cos(phi), np.sin(phi)])
                if all(np.linalg.norm(f - o) > r_rim + 0.02 for o in others):
                    return phi
        return phi0


TASK = StackBowlsThree
