"""place_object_basket: put the object into the basket, then pick the basket up.

Description
    A basket (26.5 x 24 cm, 8 cm deep) with a fixed handle arching over it from end to end (its top
    bar 9 cm above the rim, along the basket's long side, left to right) stands at the front middle
    of the table; a small object lies on one side: a toy car (8-9 cm long) or a pack of playing
    cards (8.9 x 6.4 x 2 cm). The robot must put the object into the basket and then pick the
    basket up (with the object in it).

Randomisation (per seed; FACTS B.6)
    The object's side ("the arm", upstream's random arm choice) is drawn first: left or right.
    Basket model {0, 1} (upstream's ``110_basket`` ids) at x = +0.02 when the object is on the
    left (-0.02 when on the right), y in [-0.08, -0.05], no rotation. Object: a pack of playing
    cards (``081_playingcards`` {0, 1, 2}) or a toy car (``057_toycar`` {0..5}), type first then
    model, at x in [-0.25, -0.20] (left) or [0.20, 0.25], y in [-0.1, 0.1], its length along
    world y (the car facing away from the robot), yaw +-pi/6.

Success (final state; upstream's predicate, axes renamed for this model)
    ``basket_raised``: basket z - its initial z > 0.02;
    ``object_raised``: object z - its initial z > 0.02;
    ``basket_upright``: the basket's up axis (its body z; upstream's mesh has y up) has a world-z
    component > 0.5;
    ``object_near_basket``: |dx| + |dy| + |dz| < 0.15 between the object's and the basket's
    origins;
    ``object_off_table``: the object does not touch the table;
    ``object_touches_basket``: the object touches the basket.
    Initial z: the spawn poses (the scene settles them by < 1 mm).
    Guard: neither the basket nor the object may fall off the table.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule, box, cylinder, sphere
from cab_core.contracts.scene import Body, SceneSpec
from cab_core.contracts.verifier import Evaluation, Verifier, WorldView, margin_above, margin_below
from cab_core.geometry import quat_to_mat, transform_point
from cab_core.kits.oracle import OPEN, TOLERANT, Hands, OracleFailed, closest_opening, top_down_quat
from cab_core.kits.scene import DESTRUCTIVE_DROP, pose_list, rand_pose, yaw_of
from cab_core.kits.task import arm_names

from ..assets_placing import (
    CARDS_MASS,
    HANDLED_BASKETS,
    HB_MASS,
    PLAYING_CARDS,
    TOY_CAR_MASS,
    TOY_CARS,
    handled_basket_shapes,
    playing_cards_shapes,
    toy_car_shapes,
)
from ..common import CodeActionTask
from .place_bread_basket import grasp_tcp_dz

RISE = 0.02
UPRIGHT = 0.5
NEAR_L1 = 0.15
SLOT_Y = -0.058  # the object's place in the basket: the front half, under the handle's side
RELEASE_GAP = 0.004
PICK_TRIES = 3  # picks of the object before the oracle gives up


class PlaceObjectBasketVerifier(Verifier):
    scoring = "final"

    def __init__(self, info: dict[str, Any]):
        self.basket = info["basket"]["name"]
        self.object = info["object"]["name"]
        self.basket_z0 = float(info["basket"]["pose"][2])
        self.object_z0 = float(info["object"]["pose"][2])
        self.guarded_objects = (self.object, self.basket)
        self.guard_min_z = float(info["table_top_z"]) - DESTRUCTIVE_DROP

    def evaluate(self, w: WorldView) -> Evaluation:
        bp, op = w.pose(self.basket), w.pose(self.object)
        up = float(quat_to_mat(bp[3:])[2, 2])
        l1 = float(np.sum(np.abs(np.asarray(op[:3]) - np.asarray(bp[:3]))))
        preds = {
            "basket_raised": bool(bp[2] - self.basket_z0 > RISE),
            "object_raised": bool(op[2] - self.object_z0 > RISE),
            "basket_upright": up > UPRIGHT,
            "object_near_basket": l1 < NEAR_L1,
            "object_off_table": not w.in_contact(self.object, "table"),
            "object_touches_basket": bool(w.in_contact(self.object, self.basket)),
        }
        values = {"basket_rise": float(bp[2] - self.basket_z0), "object_rise": float(op[2] - self.object_z0),
                  "basket_up_z": up, "object_basket_l1": l1}
        # the two contact predicates are events without a threshold: no margin
        margins = {
            "basket_raised": margin_above(bp[2] - self.basket_z0, RISE, "m"),
            "object_raised": margin_above(op[2] - self.object_z0, RISE, "m"),
            "basket_upright": margin_above(up, UPRIGHT, "up-axis z component"),
            "object_near_basket": margin_below(l1, NEAR_L1, "m"),
        }
        return Evaluation(success=all(preds.values()), predicates=preds, values=values, margins=margins)


class PlaceObjectBasket(CodeActionTask):
    verifier_class = PlaceObjectBasketVerifier
    # (1) the object near and touching the basket; (2) the basket raised > 2 cm; (3) everything
    # together (the raised upright basket carrying the raised object off the table)
    subgoal_predicates = (("object_near_basket", "object_touches_basket"), ("basket_raised",),
                          ("basket_raised", "object_raised", "basket_upright", "object_near_basket", "object_off_table",
                           "object_touches_basket"))

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        side = -1.0 if rng.random() < 0.5 else 1.0  # the object's side (-1: left)
        basket_id = int(rng.integers(0, len(HANDLED_BASKETS)))
        bshapes, bdims = handled_basket_shapes(basket_id)
        basket_pose = rand_pose(rng, (-0.02 * side,), (-0.08, -0.05), (top + 0.0005,))

        if rng.random() < 0.5:
            kind, model = "playingcards", int(rng.integers(0, len(PLAYING_CARDS)))
            oshapes, odims = playing_cards_shapes(model)
            mass = CARDS_MASS
        else:
            kind, model = "toycar", int(rng.integers(0, len(TOY_CARS)))
            oshapes, odims = toy_car_shapes(model)
            mass = TOY_CAR_MASS
        h = odims["size"][2]
        q0 = (float(np.cos(np.pi / 4)), 0.0, 0.0, float(np.sin(np.pi / 4)))  # length along world y
        xlim = (-0.25, -0.20) if side < 0 else (0.20, 0.25)
        obj_pose = rand_pose(rng, xlim, (-0.1, 0.1), (top + h / 2 + 0.001,), rotate_rand=True,
                             rotate_lim=(0.0, 0.0, np.pi / 6), qpos=q0)

        scene.bodies.append(Body("basket", bshapes, pose=tuple(basket_pose), kind="dynamic", mass=HB_MASS))
        scene.bodies.append(Body("object", oshapes, pose=tuple(obj_pose), kind="dynamic", mass=mass))
        gdz = grasp_tcp_dz(h, top, float(obj_pose[2]))
        obj_arm = "left" if side < 0 else "right"
        info = {
            "arms": list(arm_names(embodiment)),
            "rise": RISE,
            "upright_min": UPRIGHT,
            "near_l1": NEAR_L1,
            "basket": {
                "name": "basket",
                "frame": "basket body: origin at the centre of its bottom face, x along its long side and the "
                         "handle bar, z up",
                **bdims,
                "pose": pose_list(basket_pose),
            },
            "object": {
                "name": "object",
                "type": kind,
                "frame": "object body: centre of its bounding box, x along its length, y across (grasp), z up",
                **odims,
                "pose": pose_list(obj_pose),
                "yaw": round(yaw_of(obj_pose[3:]), 6),
                "grasp_tcp_dz": round(gdz, 6),
            },
            "object_arm": obj_arm,
            "basket_arm": "right" if obj_arm == "left" else "left",
            "slot_in_basket": [0.0, SLOT_Y, bdims["floor_top_z"]],  # the expert's place (basket frame)
            # expert release: TCP above the basket origin, at the slot
            "release_tcp_dz": round(bdims["floor_top_z"] + RELEASE_GAP + h / 2 + gdz, 6),
        }
        return info

    # --- checkpoints ---------------------------------------------------------------------------
    def spatial_checkpoints(self, info: dict) -> list[SpatialRule]:
        obj, bk = info["object"], info["basket"]
        slot = np.asarray(info["slot_in_basket"], float)
        rdz = float(info["release_tcp_dz"]) - float(bk["floor_top_z"])
        bar = np.asarray(bk["handle_bar_point"], float)
        return [
            SpatialRule("Approach object", "either",
                        lambda w: np.asarray(w.pose(obj["name"])[:3], float) + [0.0, 0.0, obj["grasp_tcp_dz"]],
                        sphere(2)),
            SpatialRule("Place in basket", "either",
                        lambda w: transform_point(w.pose(bk["name"]), slot) + [0.0, 0.0, rdz],
                        cylinder(7, (-2, 4)), prerequisites=(0,)),
            SpatialRule("Approach basket", "either", lambda w: transform_point(w.pose(bk["name"]), bar),
                        box(10, 4, (-3, 8))),
            SpatialRule("Basket lift", "either", None, None, prerequisites=(2,), lift_above_cm=2.0),
        ]

    # --- reference solution ----------------------------------------------------------------------
    def solve(self, call, world: WorldView) -> None:
        """The arm on the object's side picks it top-down (a pack of cards pinched across its
        width, a toy car along its length, pads on its bumpers: see ``grasp_axis``), checks that
        every finger holds it, carries it high over the basket with the fingers open along +x, lays
        it on the basket floor in the front half (beside the handle's line, fingers along the
        handle) and lets go, then steps aside. An object that slips out on the way is picked again
        from where it fell. The other arm takes the handle bar from above, fingers across it, and
        lifts the basket 10 cm."""
        self._put_object_in(call, world)
        self._lift_basket(call, world)
        call("done", report="put the object into the basket and lifted the basket by its handle", success_claim=True)

    @staticmethod
    def _put_object_in(call, world: WorldView) -> None:
        """Steps 1 and 2, the object's arm: the object picked, laid in the basket's front half, let
        go; then the arm steps aside. From a later stage (a fork; ``keeps_hands``): an object resting
        in the basket, in no hand, stays there; one the object's arm holds is not picked again (and
        is let go at once where it touches the basket already)."""
        info = world.info
        obj, bk = info["object"], info["basket"]
        name = obj["name"]
        o_arm = info["object_arm"]
        hands = Hands(call, o_arm)
        qr = top_down_quat([1.0, 0.0, 0.0])
        h = float(obj["size"][2])

        def target(held: np.ndarray) -> np.ndarray:
            slot = transform_point(world.pose(bk["name"]), info["slot_in_basket"])
            return np.array([slot[0] - held[0], slot[1] - held[1], slot[2] + RELEASE_GAP + h / 2 - held[2]])

        obj_done = _in_basket(world, name, bk["name"]) and not any(world.gripper_holds(a, name) for a in info["arms"])
        if not obj_done:
            held = world.gripper_holds(o_arm, name)
            if not held and world.gripper_command(o_arm) < OPEN:
                hands.grip(1.0)
            for attempt in range(PICK_TRIES):
                if not (attempt == 0 and held):
                    # 1. pick the object (lifted 20 cm: clear of the handle on the way to the basket)
                    hands.pick_top_down(world, name, float(obj["grasp_tcp_dz"]), lift=0.20, across=grasp_axis(obj))
                    if not world.gripper_holds(o_arm, name):
                        hands.grip(1.0)  # it slipped out on the lift: open, pick it again where it lies
                        continue
                elif _down_in_basket(world, info):  # held, down in the basket already: let go
                    hands.grip(1.0)
                    hands.move(dz=0.10, what="retreat", ok=TOLERANT)
                    break
                elif world.in_contact(name, "table"):  # held, still on the table: lift it first
                    hands.move(dz=0.20, what="lift", ok=TOLERANT)
                # 2. into the basket's front half: fingers open along +x (the wrist camera toward the robot),
                # from high above: the carried object clears the handle (its bar 17 cm above the table)
                tcp = world.tcp_pose(o_arm)
                held0 = quat_to_mat(qr) @ (quat_to_mat(tcp[3:]).T @ (world.pose(name)[:3] - tcp[:3]))
                hands.reach(target(held0) + [0.0, 0.0, 0.26], qr, "above the place")
                if not world.gripper_holds(o_arm, name):  # lost on the way: never aim at where it fell
                    hands.grip(1.0)
                    if _in_basket(world, name, bk["name"]):
                        break
                    hands.move(dz=0.05, what="clear of the basket", ok=TOLERANT)
                    continue
                # the place from where the object now sits in the hand
                t = target(world.pose(name)[:3] - world.tcp_pose(o_arm)[:3])
                hands.move_to(world, t, "down to the place", ok=TOLERANT)
                hands.grip(1.0)
                hands.move(dz=0.10, what="retreat", ok=TOLERANT)
                break
            else:
                raise OracleFailed(f"{name}: not held over the basket after {PICK_TRIES} picks")
        if obj_done and _hand_in_basket(world, info):  # just let go: up first (taking the hand away
            hands.move(dz=0.10, what="retreat", ok=TOLERANT)  # low drags the basket along)
        if not obj_done or np.linalg.norm(world.tcp_pose(o_arm)[:2] - world.pose(bk["name"])[:2]) < 0.15:
            hands.move(dx=-0.18 if o_arm == "left" else 0.18, dz=0.05, what="step aside", ok=TOLERANT)

    def _lift_basket(self, call, world: WorldView) -> None:
        """Step 3, the other arm: the handle bar from above, fingers across it (along y), and up by
        10 cm (the planned reach turns the wrist and dips the hand ~8 cm on the way: rise first and
        come from 20 cm above the bar, so the fingers pass over the handle). From a fork, a basket
        this arm holds, or is open around the handle of, is lifted from there."""
        info = world.info
        bk, b_arm = info["basket"], info["basket_arm"]
        lifter = Hands(call, b_arm)
        if world.gripper_holds(b_arm, bk["name"]):
            if not self.evaluate(world).predicates["basket_raised"]:
                lifter.move(dz=0.10, what="lift", ok=TOLERANT)
        elif _at_handle(world, info):
            lifter.grip(0.0)
            lifter.move(dz=0.10, what="lift", ok=TOLERANT)
        else:
            if world.gripper_command(b_arm) < OPEN:
                lifter.grip(1.0)
            lifter.move(dz=0.15, what="rise before turning the wrist", ok=TOLERANT)
            qb = top_down_quat(closest_opening(world.tcp_pose(b_arm)[3:], [np.array([0.0, 1.0, 0.0])]))
            lifter.pick_top_down(world, bk["name"], float(bk["handle_bar_point"][2]), hover=0.20, lift=0.10, quat=qb)
        # a basket hanging from its handle still sways after the lift: hold it closed a moment so
        # the object rests in it again before reporting
        lifter.grip(0.0)

    def keeps_hands(self, world: WorldView) -> bool:
        """Whether the object's arm holds the object or is open down in the basket (the object just
        let go), or the basket's arm holds the basket or is open around its handle: then the
        solution goes on from the hands as they are."""
        info = world.info
        return bool(world.gripper_holds(info["object_arm"], info["object"]["name"])
                    or world.gripper_holds(info["basket_arm"], info["basket"]["name"]) or _at_handle(world, info)
                    or _hand_in_basket(world, info))


def grasp_axis(obj: dict) -> tuple[float, float, float]:
    """The object's axis the fingers close along. A pack of cards: across its width (y; 6.4 cm,
    its length does not fit). A toy car: along its length (x; 7.8-8.8 cm between the pads' 9.2 cm
    open clearance), on the end faces of its body box. Across its width the pads also meet the
    narrower cabin once the car tilts a little: on PyBullet the pinched car then rolls about its
    length and slides out within a 20 cm lift (heldout seeds 101, 103)."""
    return (1.0, 0.0, 0.0) if obj["type"] == "toycar" else (0.0, 1.0, 0.0)


def _at_handle(world: WorldView, info: dict) -> bool:
    """Whether the basket's arm is open around the handle bar, pointing down, at the grasp (a
    grasp under way)."""
    arm, bk = info["basket_arm"], info["basket"]
    tcp = world.tcp_pose(arm)
    grasp = np.asarray(world.pose(bk["name"])[:3]) + [0.0, 0.0, float(bk["handle_bar_point"][2])]
    return bool(world.gripper_command(arm) >= OPEN and quat_to_mat(tcp[3:])[2, 0] < -0.99
                and np.linalg.norm(tcp[:3] - grasp) < 0.015)


def _hand_in_basket(world: WorldView, info: dict) -> bool:
    """Whether the object's arm is open with its TCP over the basket, less than 5 cm above its rim
    (where the object is let go; the solution retreats 10 cm up from there)."""
    bk = info["basket"]
    bp = world.pose(bk["name"])
    arm = info["object_arm"]
    local = quat_to_mat(bp[3:]).T @ (world.tcp_pose(arm)[:3] - bp[:3])
    hx, hy = (float(v) for v in bk["outer_half_size"])
    return bool(world.gripper_command(arm) >= OPEN and abs(local[0]) < hx and abs(local[1]) < hy
                and local[2] < float(bk["rim_z"]) + 0.05)


def _down_in_basket(world: WorldView, info: dict) -> bool:
    """Whether the object's centre is inside the basket, below its rim."""
    bk = info["basket"]
    bp = world.pose(bk["name"])
    local = quat_to_mat(bp[3:]).T @ (np.asarray(world.pose(info["object"]["name"])[:3]) - bp[:3])
    hx, hy = (float(v) for v in bk["inner_half_size"])
    return bool(abs(local[0]) < hx and abs(local[1]) < hy and local[2] < float(bk["rim_z"]))


def _in_basket(world: WorldView, name: str, basket: str) -> bool:
    """The object, dropped, came to rest in the basket (touching it, off the table)."""
    return bool(world.in_contact(name, basket)) and not world.in_contact(name, "table")


TASK = PlaceObjectBasket
