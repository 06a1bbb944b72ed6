"""lift_pot: lift the kitchen pot with both arms, keeping it level.

Description
    A kitchen pot (an open cooking pot, no lid) stands in the middle of the table with its two side
    handles, flat tabs sticking out of the wall just below the rim, pointing roughly left and right.
    The robot must take one handle in each gripper and lift the pot, keeping it upright.

Randomisation (per seed)
    Model variant 0 or 1 (as upstream's ``060_kitchenpot`` ids {0, 1}): a red enamel pot, 17 cm
    across and 9.5 cm tall, or a stainless one, 16 x 8.5 cm; both with 4 cm handle tabs (3 cm wide,
    1.6 cm thick, their tops 1.2 cm below the rim; 24-25 cm from handle end to handle end) and a
    mass of 0.65-0.75 kg. Drawn with ``rand_pose``:
    x, y in [-0.05, 0.05], yaw in +-pi/8 (FACTS B.6); the pot stands on the table (its origin,
    the centre of its bottom, 0.2 mm above the table top).

Success (final state)
    ``pot_raised``: the pot's origin (centre of its bottom) is above z = 0.82 (table top 0.74: a lift
    of 8 cm);
    ``left_at_handle``: the left TCP is within 0.03 m of the pot's contact point 0 (the centre of the
    -x handle);
    ``right_at_handle``: the right TCP is within 0.03 m of contact point 1 (the +x handle);
    ``pot_upright``: the pot's up axis has a dot product > 0.8 with world +z.
    Guard: the pot must not fall off the table.
    Margins are recorded for all four predicates.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, cylinder
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_above, margin_below
from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.oracle import TOLERANT, BothHands, OracleFailed, closest_opening, top_down_quat, yaw_axis
from cab_core.kits.scene import DESTRUCTIVE_DROP, draw_variant, pose_list, rand_pose, vec, yaw_of

from ..assets_pots import POT_VARIANTS, pot_geometry, pot_shapes
from ..common import CodeActionTask, lift_rules

MODEL_IDS = (0, 1)
RAISED_Z = 0.82  # absolute (table top 0.74)
HANDLE_TOLERANCE = 0.03
UPRIGHT_DOT = 0.8
LIFT_M = 0.13  # the oracle's lift


class LiftPotVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        p = info["pot"]
        self.pot = p["name"]
        self.handles = [np.asarray(h, float) for h in p["handle_points"]]
        self.raised_z = float(info["raised_z"])
        self.tol = float(info["handle_tolerance"])
        self.lift = self.raised_z - float(info["table_top_z"])  # the lift ``pot_raised`` asks for (8 cm)
        self.guarded_objects = (self.pot,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        pose = w.pose(self.pot)
        d = {arm: float(np.linalg.norm(w.tcp_pose(arm)[:3] - transform_point(pose, h)))
             for arm, h in zip(("left", "right"), self.handles)}
        up = float(quat_to_mat(pose[3:])[2, 2])
        preds = {
            "pot_raised": bool(pose[2] > self.raised_z),
            "left_at_handle": d["left"] < self.tol,
            "right_at_handle": d["right"] < self.tol,
            "pot_upright": up > UPRIGHT_DOT,
        }
        return Evaluation(success=all(preds.values()), predicates=preds,
                          values={"pot_z": float(pose[2]), "left_handle_dist": d["left"],
                                  "right_handle_dist": d["right"], "pot_up_dot_z": up},
                          margins={"pot_raised": margin_above(pose[2], self.raised_z, "m", self.lift),
                                   "left_at_handle": margin_below(d["left"], self.tol, "m"),
                                   "right_at_handle": margin_below(d["right"], self.tol, "m"),
                                   "pot_upright": margin_above(up, UPRIGHT_DOT, "dot product", 1 - UPRIGHT_DOT)})


class LiftPot(CodeActionTask):
    verifier_class = LiftPotVerifier
    subgoal_predicates = (("left_at_handle",), ("right_at_handle",), ("pot_raised",),
                          ("pot_raised", "left_at_handle", "right_at_handle", "pot_upright"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id, v = draw_variant(rng, POT_VARIANTS, MODEL_IDS)
        pose = rand_pose(rng, (-0.05, 0.05), (-0.05, 0.05), (top + 2e-4,), rotate_rand=True,
                         rotate_lim=(0.0, 0.0, np.pi / 8))
        scene.bodies.append(Body("pot", pot_shapes(v, model_id), pose=tuple(pose), kind="dynamic", mass=v.mass,
                                 angular_damping=0.1))
        g = pot_geometry(v)
        info = {
            "raised_z": RAISED_Z,
            "handle_tolerance": HANDLE_TOLERANCE,
            "upright_dot": UPRIGHT_DOT,
            "pot": {
                "name": "pot",
                "model_id": model_id,
                "frame": "pot body: origin at the centre of the bottom, +z up along the axis, handles along "
                         "-x (contact point 0) and +x (contact point 1)",
                "initial_pose": pose_list(pose),
                "yaw": round(yaw_of(pose[3:]), 6),
                "initial_z": round(float(pose[2]), 6),
                "radius": g["radius"],
                "height": g["height"],
                "handle_points": [vec(x) for x in g["handle_points"]],  # contact points 0, 1
                "handle_size": vec(g["handle_size"]),  # radial, tangential, vertical
                "span_with_handles": round(g["span_with_handles"], 6),
                "mass_kg": g["mass_kg"],
                "up_axis": vec(g["up_axis"]),
            },
            "handle_arms": ["left", "right"],  # contact point 0 for the left arm, 1 for the right
        }
        return info

    # --- checkpoints ---------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        p = info["pot"]
        name = p["name"]

        def handle(i: int):
            # the oracle's TCP sits on the handle's centre (TCP-to-object offset 0)
            return lambda w: transform_point(w.pose(name), p["handle_points"][i])

        return [
            SpatialRule("Approach left handle", "left", handle(0), cylinder(2.0, 3.0)),
            SpatialRule("Approach right handle", "right", handle(1), cylinder(2.0, 3.0)),
            *lift_rules(info, p["initial_z"]),
        ]

    # --- reference solution ----------------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """Both grippers come down top-down onto the handle tabs (fingers across each tab, closing
        on its sides), close, and lift together with paired Cartesian moves (6 tool calls)."""
        p = world.info["pot"]
        pose = world.pose(p["name"])
        h = [transform_point(pose, x) for x in p["handle_points"]]
        tangent = yaw_axis(pose[3:], (0.0, 1.0, 0.0))  # the handles' width runs along the pot's y
        q = {arm: top_down_quat(closest_opening(world.tcp_pose(arm)[3:], [tangent])) for arm in ("left", "right")}
        hover = 0.20  # measured: from 0.16 the wrist turning to top-down still grazes the pot
        both = BothHands(call)
        both.reach({"left": vec(h[0] + [0, 0, hover]), "right": vec(h[1] + [0, 0, hover])},
                   {a: vec(q[a]) for a in both.ARMS}, "hover above the handles")
        now = {arm: world.tcp_pose(arm)[:3] for arm in both.ARMS}
        both.move({"left": vec(h[0] - now["left"]), "right": vec(h[1] - now["right"])}, "down onto the handles",
                  TOLERANT)
        both.grip(0.0, "close")
        r = call("move_both_delta", left_delta=[0.0, 0.0, LIFT_M], right_delta=[0.0, 0.0, LIFT_M])
        if r.get("status") is None:
            raise OracleFailed(f"lift: {r}")
        call("done", report="lifted the pot level by both handles", success_claim=True)


TASK = LiftPot
