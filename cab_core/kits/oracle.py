"""Building blocks of the reference solutions (oracles): grasp orientations, :class:`Hands` and
:class:`BothHands` (moves through the public tools), and :func:`resume`, which runs a task's
solution from any state an attempt can reach. Oracles read privileged state (through the
``WorldView``) only to compute targets; every action goes through the public tools (``call``).
Quaternions are [qw, qx, qy, qz], computed locally from axes, as an agent could do with
``grasp_quat_candidates``; positions and moves in metres."""
from __future__ import annotations

import numpy as np

from cab_core.contracts.task import NotRecoverable
from cab_core.errors import CabError
from cab_core.geometry import mat_to_quat, quat_to_mat, transform_point


class OracleFailed(CabError):
    """The reference solution could not complete a step (reported in the record)."""


def tcp_quat(approach, opening) -> list[float]:
    """TCP orientation with +x = approach and +y = opening line (orthogonalised)."""
    a = np.asarray(approach, float)
    a = a / np.linalg.norm(a)
    o = np.asarray(opening, float)
    o = o - np.dot(o, a) * a
    o = o / np.linalg.norm(o)
    return [float(v) for v in mat_to_quat(np.stack([a, o, np.cross(a, o)], axis=1))]


def top_down_quat(opening_xy) -> list[float]:
    """Approach straight down; fingers open along ``opening_xy`` (a horizontal line)."""
    o = np.array([opening_xy[0], opening_xy[1], 0.0])
    return tcp_quat([0.0, 0.0, -1.0], o)


def yaw_axis(quat, axis=(1.0, 0.0, 0.0)) -> np.ndarray:
    """A body axis in the world, projected to the table plane and normalised."""
    v = quat_to_mat(quat) @ np.asarray(axis, float)
    v[2] = 0.0
    n = np.linalg.norm(v)
    return v / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])


def world_point(pose, local) -> np.ndarray:
    return transform_point(np.asarray(pose, float), local)


def closest_opening(current_quat, candidates: list[np.ndarray]) -> np.ndarray:
    """Of the horizontal opening lines, the one needing the least wrist roll from now (the line
    is unoriented, so both signs are tried)."""
    cur = quat_to_mat(current_quat)[:, 1]
    best, score = None, -1.0
    for c in candidates:
        for s in (1.0, -1.0):
            d = float(np.dot(cur, s * np.asarray(c)))
            if d > score:
                best, score = s * np.asarray(c), d
    if best is None:
        raise ValueError("closest_opening: no candidate opening lines (or none of finite length)")
    return best


def finger_reach(opening: float) -> float:
    """For the two-finger gripper the reference oracles are written for: TCP to a finger's outer side along the opening line at gripper command
    ``opening`` (the pads' clearance is 0.11 * opening - 0.018 m)."""
    return 0.024 + 0.055 * opening


def fingers_clear(centre_xy, line, opening: float, obstacles, margin: float = 0.01) -> bool:
    """Whether both fingers, opened to ``opening`` along the horizontal ``line`` about
    ``centre_xy``, stay ``margin`` clear of every obstacle ``(centre_xy, radius)``."""
    reach = finger_reach(opening)
    c = np.asarray(centre_xy, float)[:2]
    d = np.asarray(line, float)[:2]
    return all(np.linalg.norm(c + s * reach * d - np.asarray(o, float)[:2]) > r + margin
               for s in (-1.0, 1.0) for o, r in obstacles)


#: every outcome of a motion after which the reference solution goes on: a guarded move that
#: stops on contact, or one that falls a little short, still leaves the TCP where the next step
#: starts from
TOLERANT = ("SUCCESS", "ABORTED", "FAILED")


def _floats(v) -> list[float]:
    return [float(x) for x in v]


def expect(result: dict, what: str, ok=("SUCCESS",)) -> dict:
    if "error" in result:
        raise OracleFailed(f"{what}: {result['error']}")
    st = result.get("status")
    if st is not None and st not in ok:
        raise OracleFailed(f"{what}: status {st} ({(result.get('failure') or {}).get('message')})")
    return result


class Hands:
    """Pick-and-place moves for one arm, through the public tools."""

    def __init__(self, call, arm: str, hover: float = 0.16):
        self.call = call
        self.arm = arm
        self.hover = hover

    def reach(self, xyz, quat=None, what="reach", ok=("SUCCESS",)) -> dict:
        args = {"arm": self.arm, "target_xyz": _floats(xyz)}
        if quat is not None:
            args["target_quat"] = _floats(quat)
        return expect(self.call("reach_tcp", **args), what, ok)

    def move(self, dx=0.0, dy=0.0, dz=0.0, *, what="move", ok=("SUCCESS",)) -> dict:
        """A straight move of the TCP by (dx, dy, dz) metres; ``what`` and ``ok`` by keyword, so that a
        displacement given as ``*delta`` cannot fill them."""
        return expect(self.call("move_delta", arm=self.arm, dx=float(dx), dy=float(dy), dz=float(dz)), what, ok)

    def move_to(self, world, xyz, what="move", ok=("SUCCESS",)) -> dict:
        """A straight move that brings the TCP to ``xyz``, from where ``world`` sees it now."""
        dx, dy, dz = np.asarray(xyz, float) - world.tcp_pose(self.arm)[:3]
        return self.move(dx, dy, dz, what=what, ok=ok)

    def move_to_height(self, world, z: float, what="move", ok=("SUCCESS",)) -> dict:
        """A straight vertical move that brings the TCP to height ``z``, from where ``world`` sees it
        now (no tool call to read it, unlike :meth:`descend_to`)."""
        return self.move(dz=z - world.tcp_pose(self.arm)[2], what=what, ok=ok)

    def turn_in_place(self, world, quat, rise: float = 0.0, what="turn the gripper") -> dict:
        """A planned reach that only turns the gripper to ``quat`` where it is (``rise`` higher): a
        reach that turns it on the way to a far target sweeps the fingers low, through what stands
        near the path."""
        xyz = world.tcp_pose(self.arm)[:3]
        if rise:
            xyz = xyz + [0.0, 0.0, rise]
        return self.reach(xyz, quat, what)

    def descend_to(self, z: float, what: str, ok=("SUCCESS",)) -> dict:
        """A straight vertical move (guarded legs) down to TCP height ``z``."""
        r = self.call("get_arm_pose", arm=self.arm)
        return self.move(dz=float(z) - float(r["tcp_pose"][2]), what=what, ok=ok)

    def grip(self, pos: float) -> dict:
        return expect(self.call("set_gripper", arm=self.arm, pos=float(pos)), "set_gripper")

    def grasp_from(self, world, start, quat, grasp, what: str, lift: float | None = None, ok=("SUCCESS",)) -> None:
        """A planned reach to ``start`` with orientation ``quat``, a straight move to ``grasp`` (from
        where ``world`` sees the TCP once there; ``ok``: the outcomes it may have), close; then, with
        ``lift``, straight up by that much. ``what`` names the target in failure messages."""
        self.reach(start, quat, f"to {what}")
        self.move_to(world, grasp, f"onto {what}", ok=ok)
        self.grip(0.0)
        if lift is not None:
            self.move(dz=lift, what="lift", ok=TOLERANT)

    def press(self, above, quat, down: float, up: float, what: str) -> None:
        """A planned reach to ``above`` (orientation ``quat``; None keeps it), straight down by
        ``down`` (a guarded move: it stops on what it presses) and straight up by ``up``."""
        self.reach(above, quat, f"above {what}")
        self.move(dz=-down, what=f"press {what}", ok=TOLERANT)
        self.move(dz=up, what="release", ok=TOLERANT)

    def pick(self, xyz, quat, lift: float = 0.10) -> None:
        """Open, hover above, descend, close, lift."""
        x, y, z = (float(v) for v in xyz)
        self.reach([x, y, z + self.hover], quat, "hover above pick")
        self.descend_to(z, "descend to grasp")
        self.grip(0.0)
        self.move(dz=lift, what="lift", ok=TOLERANT)

    def pick_held(self, world, name: str, aim, lift: float = 0.10, tries: int = 3) -> None:
        """Pick ``name`` and make sure it is held. ``aim(pose) -> (grasp_xyz, quat)`` from the
        object's pose. Once hovering above it, the pose is read again and the aim renewed if the
        object moved (the arm's planned path may have brushed it); after the lift, every finger must
        touch it, else the gripper opens and the pick starts over from where it lies."""
        for _ in range(tries):
            xyz, q = aim(world.pose(name))
            self.reach([xyz[0], xyz[1], xyz[2] + self.hover], q, "hover above pick")
            xyz2, q2 = aim(world.pose(name))
            if np.linalg.norm(np.subtract(xyz2, xyz)) > 0.003 or abs(float(np.dot(q2, q))) < 0.9995:
                xyz, q = xyz2, q2
                self.reach([xyz[0], xyz[1], xyz[2] + self.hover], q, "hover above pick again")
            self.descend_to(float(xyz[2]), "descend to grasp")
            self.grip(0.0)
            self.move(dz=lift, what="lift", ok=TOLERANT)
            if world.gripper_holds(self.arm, name):
                return
            self.grip(1.0)
        raise OracleFailed(f"{name}: not held after {tries} picks")

    def pick_top_down(self, world, name: str, dz: float, *, hover: float = 0.20, lift: float = 0.10,
                      across=(0.0, 1.0, 0.0), quat=None) -> None:
        """Open fingers across the object's ``across`` axis (or ``quat``), a planned reach to ``hover``
        above the grasp (the planned path may dip several cm: keep it high), then straight down to
        the TCP ``dz`` above the object's origin where the object is now (the reach may have nudged
        it), close, lift straight up."""
        p = world.pose(name)
        q = quat if quat is not None else top_down_quat(
            closest_opening(world.tcp_pose(self.arm)[3:], [yaw_axis(p[3:], across)]))
        self.reach([p[0], p[1], p[2] + dz + hover], q, "hover above the object")
        p = world.pose(name)
        self.move_to(world, [p[0], p[1], p[2] + dz], "down to the grasp")
        self.grip(0.0)
        self.move(dz=lift, what="lift", ok=TOLERANT)

    def place_at(self, world, tcp_target, quat, *, refine=None, hover: float = 0.16, retreat: float = 0.08,
                 open_to: float = 1.0) -> None:
        """A planned reach to ``hover`` above the TCP target, straight down to it (or to
        ``refine()``, the target recomputed from the state once above it) stopping on contact, open,
        straight up by ``retreat``."""
        self.reach(np.asarray(tcp_target, float) + [0.0, 0.0, hover], quat, "above the place")
        self.move_to(world, refine() if refine is not None else tcp_target, "down to the place", ok=TOLERANT)
        self.grip(open_to)
        self.move(dz=retreat, what="retreat", ok=TOLERANT)

    def place(self, xyz, quat=None, retreat: float = 0.08, open_to: float = 1.0) -> None:
        """Carry above, descend, release (open to ``open_to``), retreat upward."""
        x, y, z = (float(v) for v in xyz)
        self.reach([x, y, z + self.hover], quat, "carry above place")
        self.descend_to(z, "descend to place", ok=TOLERANT)
        self.grip(open_to)
        self.move(dz=retreat, what="retreat", ok=TOLERANT)

    def park(self, world, x: float, what: str = "step aside", planned_rise: float = 0.08) -> None:
        """Withdraw the TCP sideways toward x = ``x`` (a straight move of at most 0.3 m), 5 cm back and
        5 cm up, so the other arm can reach the middle (a gripper parked near it meets the other arm's
        wrist); where the straight move fails (e.g. the wrist roll at its limit), a planned reach to
        ``x`` instead, ``planned_rise`` up."""
        r = self.move(dx=float(np.clip(x - world.tcp_pose(self.arm)[0], -0.3, 0.3)), dy=-0.05, dz=0.05, what=what,
                      ok=TOLERANT)
        if r["status"] == "FAILED":
            now = world.tcp_pose(self.arm)
            self.reach([x, now[1] - 0.05, now[2] + planned_rise], None, what, ok=TOLERANT)


class BothHands:
    """Moves of both arms at once (one tool call each; targets keyed by ``"left"``, ``"right"``)."""

    ARMS = ("left", "right")

    def __init__(self, call):
        self.call = call

    def reach(self, xyz: dict, quat: dict, what: str, ok=("SUCCESS",)) -> dict:
        """Planned reaches of both TCPs to ``xyz[arm]`` with orientation ``quat[arm]``."""
        return expect(self.call("reach_both_tcp", left_xyz=_floats(xyz["left"]), right_xyz=_floats(xyz["right"]),
                                left_quat=_floats(quat["left"]), right_quat=_floats(quat["right"])), what, ok)

    def move(self, delta: dict, what: str, ok=("SUCCESS",)) -> dict:
        """Straight moves of both TCPs by ``delta[arm]``."""
        return expect(self.call("move_both_delta", left_delta=_floats(delta["left"]),
                                right_delta=_floats(delta["right"])), what, ok)

    def move_to(self, world, xyz: dict, what: str, ok=("SUCCESS",)) -> dict:
        """Straight moves that bring both TCPs to ``xyz[arm]``, from where ``world`` sees them now."""
        return self.move({a: np.asarray(xyz[a], float) - world.tcp_pose(a)[:3] for a in self.ARMS}, what, ok)

    def rise(self, dz: float, what: str, ok=("SUCCESS",)) -> dict:
        """Both TCPs straight up by ``dz``."""
        return self.move({a: [0.0, 0.0, dz] for a in self.ARMS}, what, ok)

    def grip(self, pos: float, what: str) -> None:
        """Both grippers to ``pos``, the left first."""
        for arm in self.ARMS:
            expect(self.call("set_gripper", arm=arm, pos=float(pos)), f"{what} {arm}")


# --- continuing from any state (forks) ----------------------------------------------------------
#: a TCP this far from where it started (m), or a gripper commanded below this opening, means an
#: earlier agent has acted: the hands are cleared before the reference solution starts
MOVED_TCP_M = 0.02
OPEN = 0.99
FIXTURES = ("table", "wall")  # the base scene's: never held, never guarded


def movable(world) -> list[str]:
    return [n for n in world.object_names() if n not in FIXTURES]


def verdict_now(verifier, world) -> tuple[bool, list[str]]:
    """Whether the task's final state holds now (predicates and guard), and what does not."""
    ev = verifier.evaluate(world)
    guard = verifier.guard(world)
    unmet = [k for k, v in {**ev.predicates, **guard}.items() if not v]
    return bool(ev.success) and all(guard.values()), unmet


def fallen(verifier, world) -> list[str]:
    return [k.removesuffix("_on_table") for k, ok in verifier.guard(world).items() if not ok]


def disturbed(world) -> list[str]:
    """What shows that the world is not at its start: a closed gripper, a TCP moved, a hand on an
    object. Empty at an attempt's start."""
    out = []
    start = world.start or {}
    for arm, pose in sorted((start.get("tcp") or {}).items()):
        if world.gripper_command(arm) < OPEN:
            out.append(f"{arm} gripper closed")
        if np.linalg.norm(world.tcp_pose(arm)[:3] - pose[:3]) > MOVED_TCP_M:
            out.append(f"{arm} hand moved")
        out += [f"{arm} hand on {n}" for n in movable(world) if world.gripper_touches(arm, n)]
    return out


def clear_hands(call, world) -> None:
    """Put down what each hand holds (straight down, guarded, to about the height the object
    started at), open both grippers, lift the hands clear and take them back to where they started."""
    start = world.start
    arms = sorted(start["tcp"])
    for arm in arms:
        held = [n for n in movable(world) if world.gripper_holds(arm, n) and n in start["objects"]]
        if held:
            drop = float(world.pose(held[0])[2] - start["objects"][held[0]][2])
            if drop > 0.01:
                call("move_delta", arm=arm, dz=-(drop - 0.005))
        if world.gripper_command(arm) < OPEN:
            call("set_gripper", arm=arm, pos=1.0)
    for arm in arms:
        if np.linalg.norm(world.tcp_pose(arm)[:3] - start["tcp"][arm][:3]) > MOVED_TCP_M:
            call("move_delta", arm=arm, dz=0.05)
    r = call("reach_both_tcp", **{f"{a}_xyz": _floats(start["tcp"][a][:3]) for a in arms},
             **{f"{a}_quat": _floats(start["tcp"][a][3:]) for a in arms})
    if r.get("status") != "SUCCESS":
        for arm in arms:  # one arm at a time where the pair could not be planned together
            call("reach_tcp", arm=arm, target_xyz=_floats(start["tcp"][arm][:3]),
                 target_quat=_floats(start["tcp"][arm][3:]))


def resume(task, call, world) -> None:
    """The task's reference solution (``task.solve``) from whatever state the world is in.

    1. An object off the table cannot be brought back: not recoverable.
    2. A final-state task whose state already holds: ``done`` at once.
    3. A world an agent has acted in (a closed gripper, a hand away from its start or on an
       object): put down what is held, open, take the hands back to where they started; what
       fell on the way is again not recoverable. A task whose solution goes on from busy hands
       says so (``task.keeps_hands(world)`` true): then the hands are left as they are.
    4. A state the task's solution cannot start from (``task.not_recoverable(world)``: an object
       tipped over, out of both arms' reach...): not recoverable, with the task's reason.
    5. The solution from there (it computes its targets from where the objects are now). If it
       fails, or ends with the task not holding, the reason is given instead of a claim.
    At an attempt's start steps 1-3 make no call, so a fresh attempt plays as before."""
    verifier = task.verifier_class(world.info)
    stages = {}

    def achieved() -> dict:
        try:
            return dict(zip(task.info.subgoals or [f"subgoal {i + 1}" for i in range(len(task.subgoal_predicates))],
                            task.subgoals(world)))
        except Exception:  # a predicate that cannot be read in this state
            return {}

    def check_fallen(when: str) -> None:
        off = fallen(verifier, world)
        if off:
            raise NotRecoverable("off_table", f"{', '.join(off)} fell off the table{when}", achieved())

    check_fallen("")
    stages = achieved()
    if verifier.scoring == "final" and world.start is not None:
        ok, _ = verdict_now(verifier, world)
        if ok:
            call("done", report="the task already holds; nothing left to do", success_claim=True)
            return
    if world.start is not None and task.keeps_hands(world) is False and disturbed(world):
        clear_hands(call, world)
        check_fallen(" while the hands were cleared")
    why = task.not_recoverable(world)
    if why is not None:
        raise NotRecoverable(why[0], why[1], achieved())

    def checked(tool: str, **kwargs):
        if tool == "done" and kwargs.get("success_claim") and verifier.scoring == "final":
            ok, unmet = verdict_now(verifier, world)
            if not ok:
                raise NotRecoverable("plan_incomplete", "the reference solution ran to its end but "
                                     f"{', '.join(unmet)} do not hold", stages)
        return call(tool, **kwargs)

    try:
        task.solve(checked, world)
    except OracleFailed as e:
        raise NotRecoverable("plan_failed", f"the reference solution failed from this state: {e}", stages) from None
