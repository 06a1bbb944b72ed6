"""handover_mic: one arm picks up the microphone and hands it to the other arm, which holds it
raised on its own side.

Description
    A desk microphone (a handle about 3 cm thick and 12 cm long in a small round stand, topped by
    a grille head about 5 cm across; 20 cm tall) stands near the front edge of the table, left or
    right of the centre. The arm on the microphone's side must grasp it and hand it over to the
    other arm; the receiving arm ends holding the microphone raised, on its own side of the table.

Randomisation (per seed; FACTS B.6)
    Model variant in {0, 4, 5} (upstream ``018_microphone`` ids: three colourings/sizes of the
    same design). ``rand_pose``: x in [-0.2, 0.2] redrawn until |x| >= 0.15, y in [-0.05, 0.0],
    z 0.741 (the stand's bottom, 1 mm above the table), no rotation. The grasping arm is the one on
    the microphone's side (x > 0: right); the receiving (handover) arm is the other one.

Success (final state)
    ``gripper_contact``: some gripper finger touches the microphone;
    ``receiver_closed``: the receiving arm's commanded gripper value < 0.2;
    ``grasper_open``: the grasping arm's commanded gripper value > 0.8;
    ``raised``: the head centre (functional point 0) is above z = 0.92;
    ``on_receiver_side``: the head centre's x is on the receiving arm's side (x < 0 for the left
    arm, x > 0 for the right).
    Guard: the microphone must stay on the table (not below table top - 0.08 m).
    Margins are recorded for every predicate but ``gripper_contact`` (an event).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, cylinder
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Margin, Verifier, WorldView, margin_above, margin_below
from cab_core.geometry import transform_point
from cab_core.kits.oracle import TOLERANT, Hands, OracleFailed, tcp_quat, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, sample_until
from cab_core.kits.stages import at_pose, closed, holds, near, near_point

from ..assets_handover import microphone
from ..common import CodeActionTask

MODEL_IDS = (0, 4, 5)
RAISED_Z = 0.92
GRIPPER_OPEN = 0.8
GRIPPER_CLOSED = 0.2
HANDOVER_BASE = (0.0, -0.05, 0.90)  # oracle hint: the stand's bottom centre during the handover
# margins' scales: the head rests only 0.5-1.5 cm below RAISED_Z, too narrow a band to judge a held
# microphone's height by, so 5 cm; the side is judged against the 0.15 m the microphone starts off
# the midline (on the grasping arm's side)
RAISED_SCALE_M = 0.05
SIDE_SCALE_M = 0.15


def _side_ok(arm: str, x: float) -> bool:
    return x < 0 if arm == "left" else x > 0


def _side_margin(arm: str, x: float) -> Margin:
    """The margin of ``_side_ok``."""
    return margin_below(x, 0.0, "m", SIDE_SCALE_M) if arm == "left" else margin_above(x, 0.0, "m", SIDE_SCALE_M)


class HandoverMicVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        m = info["microphone"]
        self.mic = m["name"]
        self.head = np.asarray(m["head_point"], float)
        self.grasper, self.receiver = info["grasp_arm"], info["receiver_arm"]
        self.arms = list(info["arms"])
        self.guarded_objects = (self.mic,)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        fp = transform_point(w.pose(self.mic), self.head)
        contact = any(w.gripper_touches(a, self.mic) for a in self.arms)
        g_recv, g_grasp = w.gripper_command(self.receiver), w.gripper_command(self.grasper)
        preds = {
            "gripper_contact": bool(contact),
            "receiver_closed": g_recv < GRIPPER_CLOSED,
            "grasper_open": g_grasp > GRIPPER_OPEN,
            "raised": bool(fp[2] > RAISED_Z),
            "on_receiver_side": bool(_side_ok(self.receiver, float(fp[0]))),
        }
        return Evaluation(success=all(preds.values()), predicates=preds,
                          values={"head_x": float(fp[0]), "head_y": float(fp[1]), "head_z": float(fp[2]),
                                  f"gripper_{self.receiver}": float(g_recv),
                                  f"gripper_{self.grasper}": float(g_grasp)},
                          margins={  # gripper_contact is an event (no margin)
                              "receiver_closed": margin_below(g_recv, GRIPPER_CLOSED, "gripper command"),
                              "grasper_open": margin_above(g_grasp, GRIPPER_OPEN, "gripper command", 1 - GRIPPER_OPEN),
                              "raised": margin_above(fp[2], RAISED_Z, "m", RAISED_SCALE_M),
                              "on_receiver_side": _side_margin(self.receiver, float(fp[0]))})


class HandoverMic(CodeActionTask):
    verifier_class = HandoverMicVerifier
    subgoal_predicates = (("on_receiver_side",), ("raised", "on_receiver_side", "gripper_contact"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        model_id = int(rng.choice(MODEL_IDS))
        pose = sample_until(lambda: rand_pose(rng, (-0.2, 0.2), (-0.05, 0.0)), lambda p: abs(p[0]) >= 0.15,
                            what="the microphone")
        shapes, facts = microphone(model_id)
        scene.bodies.append(Body("microphone", shapes, pose=tuple(pose), kind="dynamic", mass=facts["mass_kg"],
                                 angular_damping=0.1))
        grasp_arm = "right" if pose[0] > 0 else "left"
        receiver = "left" if grasp_arm == "right" else "right"
        info = {
            "raised_z": RAISED_Z,
            "gripper_open_threshold": GRIPPER_OPEN,
            "gripper_closed_threshold": GRIPPER_CLOSED,
            "arms": ["left", "right"],
            "grasp_arm": grasp_arm,
            "receiver_arm": receiver,
            "microphone": {
                "name": "microphone",
                "frame": "microphone body: origin at the bottom centre of its round stand, +z up along the "
                         "handle (round: x and y arbitrary)",
                "initial_pose": pose_list(pose),
                **facts,
            },
            "handover_base": list(HANDOVER_BASE),
        }
        return info

    # -- checkpoints ------------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        m = info["microphone"]
        handle = np.asarray(m["handle_point"], float)
        head = np.asarray(m["head_grasp_point"], float)
        return [
            SpatialRule("Approach microphone", "either", lambda w: transform_point(w.pose(m["name"]), handle),
                        cylinder(3.0, 3.0)),
            SpatialRule("Handover", "either", lambda w: transform_point(w.pose(m["name"]), head),
                        box(12.0, 6.0, 6.0), prerequisites=(0,)),
        ]

    # -- reference solution -----------------------------------------------------------------------
    #: the reference solution's steps, in order (a fork goes on from the step its state shows)
    STEPS = ("reach", "onto", "close", "carry", "receive", "receive_down", "receive_close", "release", "back_off",
             "side")

    def _stage(self, world: WorldView) -> str | None:
        """The first step of the reference solution still to do, read from the hands and the
        microphone (a fork); None where the state is not one the solution passes through (at an
        attempt's start too: there it starts with its first step)."""
        info = world.info
        m = info["microphone"]
        name = m["name"]
        ga, ra = info["grasp_arm"], info["receiver_arm"]
        pose = world.pose(name)
        h = transform_point(pose, m["handle_point"])
        head = transform_point(pose, m["head_grasp_point"])
        if holds(world, ra, name):
            if closed(world, ga):
                return "release"
            if near(world, ga, h, 0.03):
                return "back_off"
            return "side"
        if holds(world, ga, name):
            base = transform_point(pose, [0.0, 0.0, 0.0])
            if not near_point(base, info["handover_base"], 0.03):
                return "carry"
            q = top_down_quat([1.0, 0.0, 0.0])
            if at_pose(world, ra, head, q):
                return "receive_close"
            if at_pose(world, ra, head + [0.0, 0.0, 0.10], q):
                return "receive_down"
            return "receive"
        forward = tcp_quat([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0])
        if at_pose(world, ga, h, forward):
            return "close"
        if at_pose(world, ga, h + [0.0, -0.10, 0.0], forward):
            return "onto"
        return None

    def keeps_hands(self, world: WorldView) -> bool:
        return self._stage(world) is not None

    def solve(self, call, world: WorldView) -> None:
        """The arm on the microphone's side grasps the handle from the front, lifts the microphone
        to the handover point in front of the robot; the other arm takes the head top-down, the
        first lets go and backs off, and the receiver carries the microphone to its side, raised
        (10 tool calls). From a fork it goes on from the step the state shows (``_stage``)."""
        info = world.info
        m = info["microphone"]
        name = m["name"]
        ga, ra = info["grasp_arm"], info["receiver_arm"]
        side = 1.0 if ra == "right" else -1.0
        grasper, receiver = Hands(call, ga), Hands(call, ra)
        start = self.STEPS.index(self._stage(world) or "reach")

        def todo(step: str) -> bool:
            return self.STEPS.index(step) >= start

        # 1. grasping arm: from the front round the handle (fingers open along x), lift it to the
        # handover point
        forward = tcp_quat([0.0, 1.0, 0.0], [-1.0, 0.0, 0.0])
        # (the straight move goes to the handle as it was seen before the reach, as at the start)
        h = transform_point(world.pose(name), m["handle_point"])
        if todo("reach"):
            grasper.reach(h + [0.0, -0.10, 0.0], forward, "to the handle")
        if todo("onto"):
            grasper.move_to(world, h, "onto the handle")
        if todo("close"):
            grasper.grip(0.0)
        if todo("carry"):
            base_now = transform_point(world.pose(name), [0.0, 0.0, 0.0])
            grasper.move(*(np.asarray(info["handover_base"], float) - base_now), what="to the handover point",
                         ok=TOLERANT)

        # 2. receiving arm: top-down onto the head (from above, straight down), close
        head = transform_point(world.pose(name), m["head_grasp_point"])
        if todo("receive"):
            receiver.reach(head + [0.0, 0.0, 0.10], top_down_quat([1.0, 0.0, 0.0]), "to the head")
        if todo("receive_down"):
            receiver.move_to(world, head, "onto the head")
        if todo("receive_close"):
            receiver.grip(0.0)

        # 3. hand over: the grasping arm lets go and backs off; the receiver carries it to its side
        if todo("release"):
            grasper.grip(1.0)
        if todo("back_off"):
            grasper.move(dy=-0.10, what="back off", ok=TOLERANT)
        receiver.move(dx=side * 0.15, dz=0.03, what="to the receiver's side", ok=TOLERANT)
        if not world.gripper_touches(ra, name):
            raise OracleFailed("the receiver does not hold the microphone")
        call("done", report=f"the {ga} arm picked up the microphone and handed it to the {ra} arm, which holds it "
                            "raised on its side", success_claim=True)

TASK = HandoverMic
