"""A :class:`cab_core.contracts.planner.Planner` on maintained libraries: Pinocchio (kinematics,
Jacobians, and collision checks through its coal/hpp-fcl geometry layer), OMPL (RRTConnect) and TOPP-RA.

One kinematic model of the whole robot; per arm, a collision model of the robot alone (as in the
paper): no table, no objects, and the *other* arm is not considered either (every pair that
involves one of its links is dropped), so one arm's plan never depends on where the other arm is.
Pairs the SRDF disables (adjacent links) are dropped too. Joints that are not the arm's are held
at the embodiment's home configuration, fingers open (or closed, ``fingers``).

IK is damped least squares on Pinocchio's frame Jacobian (the closed-loop IK of Pinocchio's own
documentation, as mplib runs it), from the seed and then from random restarts; a solution must be
within joint limits, free of self-collision and within ``ik_threshold`` of the target. Joint paths
are the straight joint-space line when it is collision-free, else OMPL's RRTConnect, simplified.
Straight-line paths follow the TCP screw motion from start to target (constant twist), each
waypoint solved by IK continued from the previous one. Every path is timed by TOPP-RA under the
joint velocity/acceleration limits and sampled on the exact ``dt`` grid: row ``k`` is the
set-point for time ``k * dt``, the first row is the start and the last row is the goal.
"""
from __future__ import annotations

import gc
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.planner import IKResult, Planner, PlanResult
from cab_core.errors import ConfigError, MissingDependency, PlannerError
from cab_core.geometry import pose_inv, pose_mul, quat_angle

INSTALL = "pip install pin ompl toppra"
SHORT_MOVE_M = 0.005  # straight-line moves shorter than this may fall back to a joint-space line
SHORT_MOVE_RAD = 0.05
SEED_IK_MAX_RAD = 0.25  # ik(): the solution continued from the seed, if this near it (joint norm)
UNIQUE_RAD = 0.1  # two IK solutions nearer than this (joint norm) are the same solution
CONVERGED = 1e-6  # IK iterates until its twist error is this small (then ``ik_threshold`` decides)
STALL_ITERATIONS = 10  # IK gives a restart up when its error has not halved in this many iterations
LINE_STEP_RAD = 0.01  # collision-check resolution of a straight joint-space line (max joint change)


def _import_libs():
    try:
        import ompl.base  # noqa: F401
        import ompl.geometric  # noqa: F401
        import ompl.util  # noqa: F401
        import pinocchio  # noqa: F401
        import toppra  # noqa: F401
    except ImportError as e:  # pragma: no cover - exercised only without the libraries
        raise MissingDependency(e.name or "pinocchio/ompl/toppra", INSTALL) from e
    return pinocchio


@dataclass
class PinConfig:
    """Options (the plugin's ``cfg`` dict). Limits are per joint or one value for all joints."""
    # the same limits as the mplib planner: a 0.3 m TCP move of aloha_agilex takes 1.2-2.0 s
    joint_vel_limits: tuple[float, ...] | float = (0.55, 0.55, 0.7, 0.9, 0.9, 1.2)  # rad/s
    joint_acc_limits: tuple[float, ...] | float = (0.9, 0.9, 1.1, 1.5, 1.5, 1.8)  # rad/s^2
    planning_time: float = 2.0  # RRTConnect time limit (s, wall clock)
    rrt_range: float = 0.1
    ik_seeds: int = 20  # IK restarts: the start configuration, then random ones
    ik_threshold: float = 1e-3  # position error (m) + rotation error (rad) accepted as an IK solution
    ik_iterations: int = 100  # damped least-squares iterations per restart
    ik_damping: float = 1e-6
    screw_step_m: float = 0.005  # waypoint spacing of straight-line paths (TCP translation) ...
    screw_step_rad: float = 0.02  # ... and rotation
    seed: int = 1  # the IK restarts' and OMPL's random generators are seeded with this per query
    fingers: str = "open"  # finger joint values assumed for collision checks: open | closed

    @classmethod
    def from_dict(cls, cfg: dict) -> PinConfig:
        known = set(cls.__dataclass_fields__)
        kw = {k: v for k, v in (cfg or {}).items() if k in known}
        try:
            out = cls(**kw)
        except TypeError as e:  # pragma: no cover
            raise ConfigError(f"pin planner config: {e}") from e
        if out.fingers not in ("open", "closed"):
            raise ConfigError(f"pin planner config: fingers must be open|closed, got {out.fingers!r}")
        if not (out.ik_seeds >= 1 and out.ik_iterations >= 1 and out.planning_time > 0
                and out.rrt_range > 0 and out.screw_step_m > 0 and out.screw_step_rad > 0):
            raise ConfigError("pin planner config: ik_seeds, ik_iterations, planning_time, rrt_range and "
                              "screw steps must be positive")
        return out


def _xyzquat(pose7: np.ndarray) -> np.ndarray:
    """cab's [x y z qw qx qy qz] as Pinocchio's [x y z qx qy qz qw]."""
    return np.concatenate([pose7[:3], pose7[4:7], pose7[3:4]])


class _Arm:
    """Pinocchio and collision state for one arm."""

    def __init__(self, pin, spec: EmbodimentSpec, arm: str, cfg: PinConfig):
        self.pin = pin
        self.arm = arm
        a = spec.arms[arm]
        self.joint_names = tuple(a.joints)
        self.model = pin.buildModelFromUrdf(spec.urdf)
        self.data = self.model.createData()
        model = self.model
        idx = []
        for j in a.joints:
            if not model.existJointName(j):
                raise PlannerError(f"{arm} arm joint {j!r} not in the URDF")
            jnt = model.joints[model.getJointId(j)]
            if jnt.nq != 1 or jnt.nv != 1:
                raise PlannerError(f"{arm} arm joint {j!r} is not a one-dof joint")
            idx.append(jnt.idx_q)
        self.q_idx = np.array(idx)
        if not model.existFrame(a.tcp_link):
            raise PlannerError(f"TCP link {a.tcp_link!r} not in the URDF")
        self.tcp = model.getFrameId(a.tcp_link)
        self.limits = np.stack([model.lowerPositionLimit[self.q_idx],
                                model.upperPositionLimit[self.q_idx]], axis=1)
        self.wide = (self.limits[:, 1] - self.limits[:, 0]) > 2 * np.pi
        n = len(idx)
        self.vel = np.broadcast_to(np.asarray(cfg.joint_vel_limits, dtype=float), (n,)).copy()
        self.acc = np.broadcast_to(np.asarray(cfg.joint_acc_limits, dtype=float), (n,)).copy()
        self.base_pose = np.asarray(spec.base_pose, dtype=float)
        # the full-robot configuration assumed for everything that is not this arm
        rest = pin.neutral(model)
        for other in spec.arms.values():
            for j, q in zip(other.joints, other.home_qpos):
                rest[model.joints[model.getJointId(j)].idx_q] = q
            fq = other.gripper.open_target if cfg.fingers == "open" else 0.0
            for j in other.gripper.joints:
                k = model.joints[model.getJointId(j)].idx_q
                rest[k] = float(np.clip(fq, model.lowerPositionLimit[k], model.upperPositionLimit[k]))
        self.rest = rest
        # the robot-only collision world of this arm
        self.geom = pin.buildGeomFromUrdf(model, spec.urdf, pin.GeometryType.COLLISION)
        self.geom.addAllCollisionPairs()
        pin.removeCollisionPairs(model, self.geom, spec.srdf)
        mine = set(a.links)
        others = {link for name, o in spec.arms.items() if name != arm for link in o.links} - mine
        link_of = [model.frames[g.parentFrame].name for g in self.geom.geometryObjects]
        drop = [(cp.first, cp.second) for cp in self.geom.collisionPairs
                if link_of[cp.first] in others or link_of[cp.second] in others]
        for i, j in drop:  # by value: the bound vector's items are views that shift as pairs go
            self.geom.removeCollisionPair(pin.CollisionPair(i, j))
        self.link_of = link_of
        self.gdata = pin.GeometryData(self.geom)

    def full(self, arm_q: np.ndarray) -> np.ndarray:
        q = self.rest.copy()
        q[self.q_idx] = arm_q
        return q

    def collides(self, arm_q: np.ndarray) -> bool:
        return bool(self.pin.computeCollisions(self.model, self.data, self.geom, self.gdata,
                                               self.full(arm_q), True))

    def colliding_pairs(self, arm_q: np.ndarray) -> list[tuple[str, str]]:
        self.pin.computeCollisions(self.model, self.data, self.geom, self.gdata, self.full(arm_q), False)
        out = set()
        for k, cp in enumerate(self.geom.collisionPairs):
            if self.gdata.collisionResults[k].isCollision():
                out.add(tuple(sorted((self.link_of[cp.first], self.link_of[cp.second]))))
        return sorted(out)

    def tcp_base(self, arm_q: np.ndarray):
        """The TCP pose in the URDF root frame (a Pinocchio SE3)."""
        self.pin.framesForwardKinematics(self.model, self.data, self.full(arm_q))
        return self.data.oMf[self.tcp].copy()

    def in_limits(self, q: np.ndarray, tol: float = 0.0) -> bool:
        return bool(np.all(q >= self.limits[:, 0] - tol) and np.all(q <= self.limits[:, 1] + tol))

    def clik(self, goal, q0: np.ndarray, iterations: int, damping: float, threshold: float) -> np.ndarray | None:
        """Damped least squares on the TCP frame Jacobian from ``q0``: the arm joints reaching the
        Pinocchio SE3 ``goal`` (root frame) within ``threshold``, kept within joint limits, or None."""
        pin = self.pin
        q = q0.copy()
        lo, hi = self.limits[:, 0], self.limits[:, 1]
        eye = np.eye(6)
        history: list[float] = []
        for it in range(iterations):
            full = self.full(q)
            pin.computeJointJacobians(self.model, self.data, full)  # forward kinematics included
            pin.updateFramePlacements(self.model, self.data)
            err_m = self.data.oMf[self.tcp].actInv(goal)
            err = pin.log6(err_m).vector
            norm = float(np.linalg.norm(err))
            if norm < CONVERGED:
                break
            history.append(norm)
            # a restart stuck against joint limits or in a local minimum: given up early
            if it >= STALL_ITERATIONS and norm > 0.5 * history[it - STALL_ITERATIONS] and norm > 1e-3:
                return None
            jac = pin.getFrameJacobian(self.model, self.data, self.tcp, pin.LOCAL)[:, self.q_idx]
            jac = pin.Jlog6(err_m) @ jac
            dq = jac.T @ np.linalg.solve(jac @ jac.T + damping * eye, err)
            step = np.max(np.abs(dq))
            if step > 0.5:
                dq *= 0.5 / step
            q = np.clip(q + dq, lo, hi)
        full = self.full(q)
        pin.framesForwardKinematics(self.model, self.data, full)
        err_m = self.data.oMf[self.tcp].actInv(goal)
        if np.linalg.norm(err_m.translation) + np.linalg.norm(pin.log3(err_m.rotation)) < threshold:
            return q
        return None


class PinPlanner(Planner):
    name = "pin"

    def __init__(self, cfg: dict | None = None):
        self.cfg = PinConfig.from_dict(cfg or {})
        self.dt = 1.0 / 250.0
        self._arms: dict[str, _Arm] = {}
        self._pin = None

    # ---------------------------------------------------------------------------------------
    def setup(self, embodiment: EmbodimentSpec, dt: float) -> None:
        self._pin = _import_libs()
        if not dt > 0:
            raise ConfigError(f"planner dt must be positive, got {dt}")
        self.dt = float(dt)
        self.embodiment = embodiment
        self._arms = {arm: _Arm(self._pin, embodiment, arm, self.cfg) for arm in embodiment.arms}
        import ompl.util as ou

        ou.setLogLevel(ou.LogLevel.LOG_WARN)

    def versions(self) -> dict[str, str]:
        from importlib.metadata import PackageNotFoundError, version

        out = {}
        for dist in ("pin", "ompl", "toppra", "coal", "hpp-fcl"):
            try:
                out[dist] = version(dist)
            except PackageNotFoundError:
                if dist in ("pin", "ompl", "toppra"):
                    out[dist] = "missing"
        return out

    # ---------------------------------------------------------------------------------------
    def _arm(self, arm: str) -> _Arm:
        if not self._arms:
            raise PlannerError("planner used before setup()")
        try:
            return self._arms[arm]
        except KeyError:
            raise PlannerError(f"unknown arm {arm!r}; arms: {sorted(self._arms)}") from None

    @staticmethod
    def _as_pose(pose) -> np.ndarray | None:
        a = np.asarray(pose, dtype=float).reshape(-1)
        if a.shape != (7,) or not np.all(np.isfinite(a)) or np.linalg.norm(a[3:]) < 1e-9:
            return None
        a = a.copy()
        a[3:] /= np.linalg.norm(a[3:])
        return a

    def _goal_base(self, ap: _Arm, target_world: np.ndarray):
        return self._pin.XYZQUATToSE3(_xyzquat(pose_mul(pose_inv(ap.base_pose), target_world)))

    def fk(self, arm: str, arm_qpos) -> np.ndarray:
        ap = self._arm(arm)
        q = np.asarray(arm_qpos, dtype=float).reshape(-1)
        if q.shape != ap.q_idx.shape:
            raise PlannerError(f"fk({arm}): expected {len(ap.q_idx)} joint values, got {q.shape}")
        xq = np.asarray(self._pin.SE3ToXYZQUAT(ap.tcp_base(q)), float)
        local = np.concatenate([xq[:3], xq[6:7], xq[3:6]])
        if local[3] < 0:
            local[3:] = -local[3:]
        return pose_mul(ap.base_pose, local)

    def _errors(self, arm: str, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
        got = self.fk(arm, q)
        return float(np.linalg.norm(got[:3] - target[:3])), float(quat_angle(got[3:], target[3:]))

    @staticmethod
    def _equivalents(ap: _Arm, q: np.ndarray) -> list[np.ndarray]:
        """``q`` and its copies shifted by +-2 pi on revolute joints whose range allows it."""
        out = [q]
        for i in np.where(ap.wide)[0]:
            more = []
            for v in out:
                for k in (-1.0, 1.0):
                    w = v.copy()
                    w[i] += k * 2 * np.pi
                    if ap.limits[i, 0] - 1e-9 <= w[i] <= ap.limits[i, 1] + 1e-9:
                        more.append(w)
            out += more
        return out

    def _solve(self, ap: _Arm, goal, q0: np.ndarray) -> np.ndarray | None:
        q = ap.clik(goal, q0, self.cfg.ik_iterations, self.cfg.ik_damping, self.cfg.ik_threshold)
        if q is None or ap.collides(q):
            return None
        return q

    def _ik_all(self, ap: _Arm, target_world: np.ndarray, seed_arm: np.ndarray) -> tuple[str, list[np.ndarray]]:
        """Collision-checked IK from the seed and ``ik_seeds - 1`` random restarts (seeded, so the
        same query gives the same answer); distinct solutions sorted by distance to the seed."""
        goal = self._goal_base(ap, target_world)
        rng = np.random.default_rng(self.cfg.seed)
        lo, hi = ap.limits[:, 0], ap.limits[:, 1]
        found: list[np.ndarray] = []
        for k in range(self.cfg.ik_seeds):
            q0 = seed_arm if k == 0 else rng.uniform(lo, hi)
            q = self._solve(ap, goal, q0)
            if q is not None and all(np.linalg.norm(q - f) >= UNIQUE_RAD for f in found):
                found.append(q)
        sols: list[np.ndarray] = []
        for s in found:
            for v in self._equivalents(ap, s):
                if not any(np.allclose(v, w, atol=1e-6) for w in sols):
                    sols.append(v)
        sols.sort(key=lambda s: float(np.linalg.norm(s - seed_arm)))
        if not sols:
            return f"IK failed: no collision-free solution within {self.cfg.ik_threshold} " \
                   f"from {self.cfg.ik_seeds} starts", []
        return "Success", sols

    def ik(self, arm: str, tcp_pose_world, seed_qpos) -> IKResult:
        ap = self._arm(arm)
        target = self._as_pose(tcp_pose_world)
        if target is None:
            return IKResult(ok=False, message=f"invalid target pose {tcp_pose_world!r}")
        seed = np.clip(np.asarray(seed_qpos, float).reshape(-1), ap.limits[:, 0], ap.limits[:, 1])
        if seed.shape != ap.q_idx.shape:
            raise PlannerError(f"ik({arm}): expected {len(ap.q_idx)} seed joint values, got {seed.shape}")
        # the solution continued from the seed, when it stays near the seed; else every restart
        first = self._solve(ap, self._goal_base(ap, target), seed)
        if first is not None:
            copies = self._equivalents(ap, first)
            dist = [float(np.linalg.norm(c - seed)) for c in copies]
            best = int(np.argmin(dist))
            first = copies[best] if dist[best] < SEED_IK_MAX_RAD else None
        if first is not None:
            sols = [first]
        else:
            status, sols = self._ik_all(ap, target, seed)
            if not sols:
                return IKResult(ok=False, message=status)
        pe, re = self._errors(arm, sols[0], target)
        return IKResult(ok=True, qpos=sols[0], message="ok", position_error_m=pe, rotation_error_rad=re)

    # ---------------------------------------------------------------------------------------
    def _start_problem(self, ap: _Arm, q: np.ndarray) -> str | None:
        if q.shape != ap.q_idx.shape or not np.all(np.isfinite(q)):
            return f"start must be {len(ap.q_idx)} finite joint values, got {q!r}"
        lo, hi = ap.limits[:, 0], ap.limits[:, 1]
        bad = np.where((q < lo - 1e-3) | (q > hi + 1e-3))[0]
        if len(bad):
            names = ap.joint_names
            return "start joint(s) out of limits: " + ", ".join(
                f"{names[i]}={q[i]:.4f} not in [{lo[i]:.3f}, {hi[i]:.3f}]" for i in bad)
        pairs = ap.colliding_pairs(np.clip(q, lo, hi))
        if pairs:
            return "start state in self-collision: " + ", ".join(f"{a}/{b}" for a, b in pairs)
        return None

    def _time(self, ap: _Arm, path: np.ndarray) -> np.ndarray:
        """TOPP-RA timing of the waypoints ``path`` (a spline through them, as mplib's), sampled
        on the exact grid 0, dt, 2 dt, ...; first row = the path's start, last row = its end.
        Raises RuntimeError when TOPP-RA finds no parametrisation."""
        import toppra as ta
        import toppra.algorithm as algo
        import toppra.constraint as constraint

        path = np.asarray(path, float)
        keep = np.concatenate([[True], np.any(np.abs(np.diff(path, axis=0)) > 1e-12, axis=1)])
        path = path[keep]
        if len(path) < 2:
            return np.vstack([path[0], path[0]])
        ta.setup_logging("WARNING")
        ss = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        spline = ta.SplineInterpolator(ss / ss[-1], path)
        inst = algo.TOPPRA([constraint.JointVelocityConstraint(ap.vel),
                            constraint.JointAccelerationConstraint(ap.acc)],
                           spline, parametrizer="ParametrizeConstAccel")
        traj = inst.compute_trajectory()
        if traj is None:
            raise RuntimeError("TOPP-RA found no time parametrisation")
        dur = float(traj.duration)
        n = int(np.ceil(dur / self.dt - 1e-9)) + 1
        grid = np.minimum(np.arange(n) * self.dt, dur)
        out = np.atleast_2d(np.asarray(traj(grid), float))
        out[0] = path[0]
        out[-1] = path[-1]
        return out if len(out) >= 2 else np.vstack([path[0], path[-1]])

    def _line(self, ap: _Arm, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        """The straight joint-space line from start to goal, collision-checked every
        ``LINE_STEP_RAD``; its waypoints, or None when it collides."""
        n = int(np.ceil(np.max(np.abs(goal - start)) / LINE_STEP_RAD)) + 1
        path = np.linspace(start, goal, max(n, 2))
        if any(ap.collides(q) for q in path[1:]):
            return None
        return path

    def _rrt(self, ap: _Arm, start: np.ndarray, goals: list[np.ndarray]) -> np.ndarray | None:
        """OMPL RRTConnect from ``start`` to any of ``goals``, simplified and interpolated; None if
        no path within ``planning_time``."""
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou

        n = len(start)
        ou.RNG.setSeed(int(self.cfg.seed))
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        for i, (lo, hi) in enumerate(ap.limits):
            bounds.setLow(i, float(lo))
            bounds.setHigh(i, float(hi))
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(lambda s: not ap.collides(np.array([s[i] for i in range(n)])))
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(LINE_STEP_RAD / space.getMaximumExtent())

        def state(q):
            s = space.allocState()
            for i, v in enumerate(q):
                s[i] = float(v)
            return s

        goal = ob.GoalStates(si)
        for g in goals:
            goal.addState(state(g))
        ss.setStartState(state(start))
        ss.setGoal(goal)
        planner = og.RRTConnect(si)
        planner.setRange(float(self.cfg.rrt_range))
        ss.setPlanner(planner)
        try:
            solved = ss.solve(float(self.cfg.planning_time))
            if not solved or "Exact" not in str(solved):
                return None
            ss.simplifySolution()
            path = ss.getSolutionPath()
            pts = np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
            del path, solved
        finally:
            # OMPL's bindings (nanobind) keep these alive through reference cycles: released here, or
            # every process that planned prints "leaked instance" warnings at exit
            ss.clear()
            del ss, goal, planner, si
            gc.collect()
        # dense enough for the spline of TOPP-RA to stay near the checked straight segments
        dense = [pts[0]]
        for a, b in zip(pts[:-1], pts[1:]):
            m = max(int(np.ceil(np.max(np.abs(b - a)) / 0.05)), 1)
            dense += list(np.linspace(a, b, m + 1)[1:])
        return np.asarray(dense)

    def plan_to_pose(self, arm: str, start_qpos, tcp_pose_world, *,
                     straight_line: bool = False) -> PlanResult:
        t0 = time.perf_counter()
        ap = self._arm(arm)
        start = np.asarray(start_qpos, dtype=float).reshape(-1)

        def done(status, **kw) -> PlanResult:
            return PlanResult(status=status, dt=self.dt, planning_time_s=time.perf_counter() - t0, **kw)

        target = self._as_pose(tcp_pose_world)
        if target is None:
            return done("invalid_goal", message=f"invalid target pose {tcp_pose_world!r}")
        problem = self._start_problem(ap, start)
        if problem:
            return done("invalid_start", message=problem)
        start = np.clip(start, ap.limits[:, 0], ap.limits[:, 1])

        pe, re = self._errors(arm, start, target)
        if pe < 1e-4 and re < 1e-3:
            return done("success", positions=np.vstack([start, start]),
                        message="already at the target", position_error_m=pe, rotation_error_rad=re)

        ik_status, sols = self._ik_all(ap, target, start)
        if not sols:
            return done("no_ik", message=f"no collision-free IK solution: {ik_status}",
                        raw={"ik_status": ik_status})
        pe_move, re_move = pe, re
        pe, re = self._errors(arm, sols[0], target)
        common = dict(position_error_m=pe, rotation_error_rad=re)
        if straight_line:
            return self._plan_screw(arm, ap, start, target, sols, (pe_move, re_move), common, done)
        return self._plan_joint_space(arm, ap, start, target, sols, common, done)

    def _screw_waypoints(self, ap: _Arm, start: np.ndarray, target: np.ndarray) -> tuple[np.ndarray | None, str]:
        """Joint waypoints along the TCP's screw motion (constant twist) from its start pose to
        ``target``: each pose solved by IK continued from the previous waypoint."""
        pin = self._pin
        m0 = ap.tcp_base(start)
        m1 = self._goal_base(ap, target)
        twist = pin.log6(m1 * m0.inverse()).vector  # in the root frame
        dist = float(np.linalg.norm(m1.translation - m0.translation))
        ang = float(np.linalg.norm(pin.log3(m1.rotation @ m0.rotation.T)))
        n = max(int(np.ceil(max(dist / self.cfg.screw_step_m, ang / self.cfg.screw_step_rad))), 1)
        path = [start]
        q = start
        for k in range(1, n + 1):
            pose = pin.exp6(pin.Motion(twist * (k / n))) * m0
            nq = ap.clik(pose, q, self.cfg.ik_iterations, self.cfg.ik_damping, self.cfg.ik_threshold)
            if nq is None:
                return None, f"waypoint {k}/{n} unreachable"
            if np.max(np.abs(nq - q)) > 0.25:
                return None, f"joint jump at waypoint {k}/{n} (singularity or joint limit)"
            if ap.collides(nq) or any(ap.collides(x) for x in np.linspace(q, nq, 4)[1:-1]):
                return None, f"self-collision at waypoint {k}/{n}"
            path.append(nq)
            q = nq
        return np.asarray(path), "Success"

    def _plan_screw(self, arm: str, ap: _Arm, start: np.ndarray, target, sols: list,
                    move_errors: tuple[float, float], common: dict,
                    done: Callable[..., PlanResult]) -> PlanResult:
        """A straight TCP line; for a very small move that cannot be followed, a short joint-space line."""
        pe_move, re_move = move_errors
        way, status = self._screw_waypoints(ap, start, target)
        if way is not None:
            end = way[-1]
            pe, re = self._errors(arm, end, target)
            if pe < 0.002 and re < 0.01:
                try:
                    pos = self._time(ap, way)
                except RuntimeError as e:
                    status = f"screw path could not be timed: {e}"
                else:
                    return done("success", positions=pos, message="screw path", position_error_m=pe,
                                rotation_error_rad=re, raw={"duration_s": (len(pos) - 1) * self.dt})
            else:
                status = f"end off target by {pe:.4f} m, {re:.4f} rad"
        near = sols[0]
        if pe_move < SHORT_MOVE_M and re_move < SHORT_MOVE_RAD and np.max(np.abs(near - start)) < SHORT_MOVE_RAD:
            line = self._line(ap, start, near)
            if line is not None:
                pe, re = self._errors(arm, near, target)
                return done("success", positions=self._time(ap, line), message="short joint-space line",
                            position_error_m=pe, rotation_error_rad=re)
        return done("no_path", message=f"no straight-line (screw) path: {status}",
                    raw={"screw_status": status}, **common)

    def _plan_joint_space(self, arm: str, ap: _Arm, start: np.ndarray, target, sols: list, common: dict,
                          done: Callable[..., PlanResult]) -> PlanResult:
        """The straight joint line to the IK solution nearest the start when it is collision-free,
        else RRTConnect to that solution, then to any of the others; timed by TOPP-RA."""
        path, how = self._line(ap, start, sols[0]), "joint-space line + TOPP-RA"
        if path is None:
            how = "RRTConnect + TOPP-RA"
            for goals in ([sols[0]], sols[1:]) if len(sols) > 1 else ([sols[0]],):
                path = self._rrt(ap, start, goals)
                if path is not None:
                    break
        if path is None:
            return done("no_path", message="IK solved but no collision-free path: RRTConnect found none "
                        f"in {self.cfg.planning_time} s", attempts=len(sols), **common)
        end = min(sols, key=lambda s: float(np.linalg.norm(s - path[-1])))
        path[-1] = end
        try:
            pos = self._time(ap, path)
        except RuntimeError as e:
            return done("no_path", message=f"path could not be timed: {e}", **common)
        pe, re = self._errors(arm, end, target)
        return done("success", positions=pos, message=how, position_error_m=pe, rotation_error_rad=re,
                    raw={"duration_s": (len(pos) - 1) * self.dt})


def factory(cfg: dict) -> PinPlanner:
    _import_libs()
    return PinPlanner(cfg)
