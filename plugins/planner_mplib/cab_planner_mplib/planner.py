"""A :class:`cab_core.contracts.planner.Planner` on mplib 0.2.1 (OMPL RRTConnect or screw paths, TOPP-RA timing).

One ``mplib.Planner`` per arm, whose move group is the arm's TCP link, so targets are TCP poses
directly. The collision world is the robot alone (as in the paper): no table, no objects, and
the *other* arm is not considered either (its links are allowed to collide in the planner's
allowed-collision matrix), so one arm's plan never depends on where the other arm happens to be.

Trajectories are time-parametrised by TOPP-RA under the configured joint velocity/acceleration
limits and resampled on an exact ``dt`` grid: row ``k`` is the set-point for time ``k * dt``, the
first row is the start and the last row is the goal.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.planner import IKResult, Planner, PlanResult
from cab_core.errors import ConfigError, MissingDependency, PlannerError
from cab_core.geometry import pose_inv, pose_mul, quat_angle

INSTALL = "pip install mplib==0.2.1"
SHORT_MOVE_M = 0.005  # straight-line moves shorter than this may fall back to a joint-space line
SHORT_MOVE_RAD = 0.05
SEED_IK_MAX_RAD = 0.25  # ik(): the solution continued from the seed, if this near it (joint norm); a 3 cm leg: 0.05-0.12
_WRAP_EDGE_RAD = 0.1  # ... and not this near the edge of mplib's wrap window of a wide joint (its uniqueness distance)


def _import_mplib():
    try:
        import mplib  # noqa: F401
        import mplib.pymp  # noqa: F401
    except ImportError as e:  # pragma: no cover - exercised only without mplib
        raise MissingDependency("mplib", INSTALL) from e
    return mplib


@dataclass
class MplibConfig:
    """Options (the plugin's ``cfg`` dict). Limits are per joint or one value for all joints."""
    # with these a 0.3 m TCP move of aloha_agilex takes 1.2-2.0 s of simulated time
    joint_vel_limits: tuple[float, ...] | float = (0.55, 0.55, 0.7, 0.9, 0.9, 1.2)  # rad/s
    joint_acc_limits: tuple[float, ...] | float = (0.9, 0.9, 1.1, 1.5, 1.5, 1.8)  # rad/s^2
    planning_time: float = 2.0  # RRTConnect time limit (s, wall clock)
    rrt_range: float = 0.1
    ik_seeds: int = 20  # IK restarts: the start configuration, then random ones
    ik_threshold: float = 1e-3  # position error + quaternion distance accepted as an IK solution
    screw_qpos_step: float = 0.02  # joint-space step of screw (straight-line) paths
    seed: int = 1  # mplib's global RNG is reseeded with this before every query (OMPL needs > 0)
    fingers: str = "open"  # finger joint values assumed for collision checks: open | closed

    @classmethod
    def from_dict(cls, cfg: dict) -> MplibConfig:
        known = set(cls.__dataclass_fields__)
        kw = {k: v for k, v in (cfg or {}).items() if k in known}
        try:
            out = cls(**kw)
        except TypeError as e:  # pragma: no cover
            raise ConfigError(f"mplib planner config: {e}") from e
        if out.fingers not in ("open", "closed"):
            raise ConfigError(f"mplib planner config: fingers must be open|closed, got {out.fingers!r}")
        return out


class _ArmPlanner:
    """mplib state for one arm."""

    def __init__(self, mplib, spec: EmbodimentSpec, arm: str, cfg: MplibConfig):
        self.arm = arm
        a = spec.arms[arm]
        n = len(a.joints)
        vel = np.broadcast_to(np.asarray(cfg.joint_vel_limits, dtype=float), (n,)).copy()
        acc = np.broadcast_to(np.asarray(cfg.joint_acc_limits, dtype=float), (n,)).copy()
        self.planner = mplib.Planner(urdf=spec.urdf, srdf=spec.srdf, move_group=a.tcp_link,
                                     joint_vel_limits=vel, joint_acc_limits=acc)
        self.pin = self.planner.pinocchio_model
        names = list(self.planner.user_joint_names)
        self.arm_idx = np.array([names.index(j) for j in a.joints])
        # mplib's paths list the move-group joints in its own order; it must be the arm's order
        if not np.array_equal(self.arm_idx, np.asarray(self.planner.move_group_joint_indices)):
            raise PlannerError(f"mplib move group of {a.tcp_link} does not match the {arm} arm joints "
                               f"{a.joints} (in that order)")
        self.tcp_link_idx = self.planner.link_name_2_idx[a.tcp_link]
        self.limits = self.planner.joint_limits[self.arm_idx]
        types = [self.planner.joint_types[i] for i in self.arm_idx]
        self.wide = np.array([t.startswith("JointModelR") and (hi - lo) > 2 * np.pi
                              for t, (lo, hi) in zip(types, self.limits)])
        self.base_pose = np.asarray(spec.base_pose, dtype=float)
        self.planner.set_base_pose(mplib.Pose(self.base_pose[:3], self.base_pose[3:]))
        # the full-robot configuration assumed for everything that is not this arm
        full = np.zeros(len(names))
        for other in spec.arms.values():
            for j, q in zip(other.joints, other.home_qpos):
                full[names.index(j)] = q
            g = other.gripper
            fq = g.open_target if cfg.fingers == "open" else 0.0
            for j in g.joints:
                lo, hi = self.planner.joint_limits[names.index(j)]
                full[names.index(j)] = float(np.clip(fq, lo, hi))
        self.rest = full
        self.ik_mask = np.ones(len(names), dtype=bool)  # True = held at its start value in IK
        self.ik_mask[self.arm_idx] = False
        # other arms are not part of this arm's collision world
        acm = self.planner.planning_world.get_allowed_collision_matrix()
        mine = set(a.links)
        for other_name, other in spec.arms.items():
            if other_name == arm:
                continue
            for link in other.links:
                if link not in mine:
                    acm.set_default_entry(link, True)

    def full(self, arm_q: np.ndarray) -> np.ndarray:
        q = self.rest.copy()
        q[self.arm_idx] = arm_q
        return q


class MplibPlanner(Planner):
    name = "mplib"

    def __init__(self, cfg: dict | None = None):
        self.cfg = MplibConfig.from_dict(cfg or {})
        self.dt = 1.0 / 250.0
        self._arms: dict[str, _ArmPlanner] = {}
        self._mplib = None
        self._seed_first = True  # ik(): the solution continued from the seed first (_ik_from_seed)

    # ---------------------------------------------------------------------------------------
    def setup(self, embodiment: EmbodimentSpec, dt: float) -> None:
        self._mplib = _import_mplib()
        if not dt > 0:
            raise ConfigError(f"planner dt must be positive, got {dt}")
        self.dt = float(dt)
        self.embodiment = embodiment
        self._arms = {arm: _ArmPlanner(self._mplib, embodiment, arm, self.cfg)
                      for arm in embodiment.arms}

    def versions(self) -> dict[str, str]:
        out = {}
        try:
            import mplib

            out["mplib"] = str(getattr(mplib, "__version__", "unknown"))
        except ImportError:
            out["mplib"] = "missing"
        try:
            import toppra

            out["toppra"] = str(getattr(toppra, "__version__", "unknown"))
        except ImportError:
            pass
        return out

    # ---------------------------------------------------------------------------------------
    def _arm(self, arm: str) -> _ArmPlanner:
        if not self._arms:
            raise PlannerError("planner used before setup()")
        try:
            return self._arms[arm]
        except KeyError:
            raise PlannerError(f"unknown arm {arm!r}; arms: {sorted(self._arms)}") from None

    def _reseed(self):
        self._mplib.pymp.set_global_seed(int(self.cfg.seed))

    def _pose(self, pose7):
        return self._mplib.Pose(np.asarray(pose7[:3], float), np.asarray(pose7[3:7], float))

    @staticmethod
    def _as_pose(pose) -> np.ndarray | None:
        a = np.asarray(pose, dtype=float).reshape(-1)
        if a.shape != (7,) or not np.all(np.isfinite(a)) or np.linalg.norm(a[3:]) < 1e-9:
            return None
        a = a.copy()
        a[3:] /= np.linalg.norm(a[3:])
        return a

    def fk(self, arm: str, arm_qpos) -> np.ndarray:
        ap = self._arm(arm)
        q = np.asarray(arm_qpos, dtype=float).reshape(-1)
        if q.shape != ap.arm_idx.shape:
            raise PlannerError(f"fk({arm}): expected {len(ap.arm_idx)} joint values, got {q.shape}")
        ap.pin.compute_forward_kinematics(ap.full(q))
        pb = ap.pin.get_link_pose(ap.tcp_link_idx)
        local = np.concatenate([np.asarray(pb.p, float), np.asarray(pb.q, float)])
        return pose_mul(ap.base_pose, local)

    def _errors(self, arm: str, q: np.ndarray, target: np.ndarray) -> tuple[float, float]:
        got = self.fk(arm, q)
        return float(np.linalg.norm(got[:3] - target[:3])), float(quat_angle(got[3:], target[3:]))

    def _ik_all(self, ap: _ArmPlanner, target_world: np.ndarray, seed_arm: np.ndarray):
        """mplib IK (collision-checked, start + random restarts); solutions sorted by distance
        to the seed. Returns (status string, list of arm-joint solutions)."""
        self._reseed()
        goal_base = self._pose(pose_mul(pose_inv(ap.base_pose), target_world))
        status, sols = ap.planner.IK(goal_base, ap.full(seed_arm), mask=ap.ik_mask,
                                     n_init_qpos=self.cfg.ik_seeds, threshold=self.cfg.ik_threshold)
        if sols is None:
            return status, []
        arm_sols = []
        for s in sols:
            for v in self._equivalents(ap, np.asarray(s, float)[ap.arm_idx]):
                if not any(np.allclose(v, w, atol=1e-6) for w in arm_sols):
                    arm_sols.append(v)
        arm_sols.sort(key=lambda s: float(np.linalg.norm(s - seed_arm)))
        return status, arm_sols

    @staticmethod
    def _equivalents(ap: _ArmPlanner, q: np.ndarray) -> list[np.ndarray]:
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

    def _ik_from_seed(self, ap: _ArmPlanner, target_world: np.ndarray, seed_arm: np.ndarray) -> np.ndarray | None:
        """The solution continued from the seed: the first of mplib's IK restarts (the one from
        the seed itself, as ``Planner.IK`` of mplib 0.2.1 runs it: CLIK, joint-limit wrap,
        collision check, ``ik_threshold``), taken as its 2 pi copy nearest the seed, when that lies
        within ``SEED_IK_MAX_RAD`` of the seed; else None and :meth:`ik` runs all restarts.

        :meth:`_ik_all` ranks the same solution and its copies with the restarts' by distance to
        the seed, and another restart's solution lies at least 0.1 (mplib's uniqueness distance)
        from this one, so the two agree unless a random restart finds a distinct solution nearer
        the seed than the one CLIK reaches from it, or (handled: all restarts run) this solution
        lies within 0.1 of the edge of the window into which mplib wraps a wide joint, where
        another restart can reach it wrapped the other way, a hair nearer the seed once shifted by
        2 pi (seen once: PyBullet, open_microwave seed 1). Compared on every ``ik`` call of the
        suite's oracles (25 tasks, seeds 0 and 1, on SAPIEN, PyBullet and MuJoCo: 5327 calls, 4893
        answered here) and on legs of 0.5-3 cm from random arm configurations: the same solution,
        bit for bit, every time. One restart costs 1/20 of all twenty (about 0.6 ms against 11 ms)."""
        planner = ap.planner
        goal = self._pose(pose_mul(pose_inv(ap.base_pose), target_world))
        start = ap.full(seed_arm)
        link = planner.link_name_2_idx[planner.move_group]
        planner.robot.set_qpos(start, True)
        q, ok, _ = planner.pinocchio_model.compute_IK_CLIK(link, goal, start, ap.ik_mask)
        if not (ok and planner.wrap_joint_limit(q)):
            return None
        planner.planning_world.set_qpos_all(q[planner.move_group_joint_indices])
        if len(planner.planning_world.check_collision()) > 0:
            return None
        planner.pinocchio_model.compute_forward_kinematics(q)
        if not goal.distance(planner.pinocchio_model.get_link_pose(link)) < self.cfg.ik_threshold:
            return None
        arm_q = np.asarray(q, float)[ap.arm_idx]
        # mplib wraps a wide joint into [lo, lo + 2 pi): near that window's edge another restart may
        # land on the same solution wrapped the other way, whose 2 pi copy can be a hair nearer the seed
        lo = ap.limits[:, 0]
        r = np.mod(arm_q - lo, 2 * np.pi)
        if np.any(ap.wide & (np.minimum(r, 2 * np.pi - r) < _WRAP_EDGE_RAD)):
            return None
        copies = self._equivalents(ap, arm_q)
        dist = [float(np.linalg.norm(c - seed_arm)) for c in copies]
        best = int(np.argmin(dist))  # the first of equals, as the stable sort of _ik_all
        return copies[best] if dist[best] < SEED_IK_MAX_RAD else None

    def ik(self, arm: str, tcp_pose_world, seed_qpos) -> IKResult:
        ap = self._arm(arm)
        target = self._as_pose(tcp_pose_world)
        if target is None:
            return IKResult(ok=False, message=f"invalid target pose {tcp_pose_world!r}")
        seed = np.clip(np.asarray(seed_qpos, float).reshape(-1), ap.limits[:, 0], ap.limits[:, 1])
        first = self._ik_from_seed(ap, target, seed) if self._seed_first else None
        if first is not None:
            sols = [first]
        else:
            status, sols = self._ik_all(ap, target, seed)
            if not sols:
                return IKResult(ok=False, message=status)
        pe, re = self._errors(arm, sols[0], target)
        return IKResult(ok=True, qpos=sols[0], message="ok", position_error_m=pe, rotation_error_rad=re)

    # ---------------------------------------------------------------------------------------
    def _start_problem(self, ap: _ArmPlanner, q: np.ndarray) -> str | None:
        if q.shape != ap.arm_idx.shape or not np.all(np.isfinite(q)):
            return f"start must be {len(ap.arm_idx)} finite joint values, got {q!r}"
        tol = 1e-3
        lo, hi = ap.limits[:, 0], ap.limits[:, 1]
        bad = np.where((q < lo - tol) | (q > hi + tol))[0]
        if len(bad):
            names = self.embodiment.arms[ap.arm].joints
            return "start joint(s) out of limits: " + ", ".join(
                f"{names[i]}={q[i]:.4f} not in [{lo[i]:.3f}, {hi[i]:.3f}]" for i in bad)
        hits = ap.planner.check_for_self_collision(ap.full(np.clip(q, lo, hi)))
        if hits:
            pairs = sorted({tuple(sorted((h.link_name1, h.link_name2))) for h in hits})
            return "start state in self-collision: " + ", ".join(f"{a}/{b}" for a, b in pairs)
        return None

    def _resample(self, times: np.ndarray, pos: np.ndarray, start: np.ndarray,
                  goal: np.ndarray) -> np.ndarray:
        """Positions on the exact grid 0, dt, 2 dt, ...; first row = start, last row = goal."""
        times = np.asarray(times, float)
        pos = np.asarray(pos, float)
        if len(times) < 2 or times[-1] <= 0:
            return np.vstack([start, goal])
        n = int(np.ceil(times[-1] / self.dt - 1e-9)) + 1
        grid = np.minimum(np.arange(n) * self.dt, times[-1])
        out = np.stack([np.interp(grid, times, pos[:, j]) for j in range(pos.shape[1])], axis=1)
        out[0] = start
        out[-1] = goal
        return out

    def _interpolate(self, ap: _ArmPlanner, start: np.ndarray,
                     goal: np.ndarray) -> np.ndarray | None:
        """A collision-checked straight joint-space line, TOPP-timed; None if it collides."""
        n = int(np.ceil(np.max(np.abs(goal - start)) / 0.01)) + 2
        path = np.linspace(start, goal, max(n, 4))
        for q in path:
            if ap.planner.check_for_self_collision(ap.full(q)):
                return None
        try:
            times, pos, *_ = ap.planner.TOPP(path, self.dt)
        except RuntimeError:
            return None
        if len(times) < 2:
            return np.vstack([start, goal])
        return self._resample(times, pos, start, goal)

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
                        raw={"mplib_status": ik_status})
        pe_move, re_move = pe, re
        pe, re = self._errors(arm, sols[0], target)
        common = dict(position_error_m=pe, rotation_error_rad=re)

        if straight_line:
            return self._plan_screw(arm, ap, start, target, sols, (pe_move, re_move), common, done)
        return self._plan_joint_space(arm, ap, start, target, sols, common, done)

    def _plan_screw(self, arm: str, ap, start: np.ndarray, target, sols: list, move_errors: tuple[float, float],
                    common: dict, done: Callable[..., PlanResult]) -> PlanResult:
        """A straight TCP line (mplib's screw motion); for a move too small for the screw integrator,
        a short joint-space line. ``move_errors``: the start's position and rotation errors."""
        pe_move, re_move = move_errors
        self._reseed()
        try:
            res = ap.planner.plan_screw(self._pose(target), ap.full(start),
                                        qpos_step=self.cfg.screw_qpos_step, time_step=self.dt,
                                        wrt_world=True)
        except RuntimeError as e:  # TOPP-RA could not time the path
            res = {"status": f"screw path could not be timed: {e}"}
        ok = res.get("status") == "Success" and len(res.get("position", ())) > 0
        if ok:
            end = np.asarray(res["position"][-1], float)
            pe, re = self._errors(arm, end, target)
            ok = pe < 0.002 and re < 0.01
        if ok:
            pos = self._resample(res["time"], res["position"], start, end)
            return done("success", positions=pos, message="screw path", position_error_m=pe,
                        rotation_error_rad=re, raw={"duration_s": float(res["duration"])})
        # a move too small for the screw integrator: a short joint-space line is straight enough
        near = sols[0]
        if pe_move < SHORT_MOVE_M and re_move < SHORT_MOVE_RAD \
                and np.max(np.abs(near - start)) < SHORT_MOVE_RAD:
            pos = self._interpolate(ap, start, near)
            if pos is not None:
                pe, re = self._errors(arm, near, target)
                return done("success", positions=pos, message="short joint-space line",
                            position_error_m=pe, rotation_error_rad=re)
        return done("no_path", message=f"no straight-line (screw) path: {res.get('status')}",
                    raw={"mplib_status": res.get("status")}, **common)

    def _plan_joint_space(self, arm: str, ap, start: np.ndarray, target, sols: list, common: dict,
                          done: Callable[..., PlanResult]) -> PlanResult:
        """A collision-free joint-space path (RRTConnect, timed by TOPP-RA) to one of the IK solutions ``sols``."""
        # the IK solution nearest the start first (short, predictable motions), then any of them
        res = {}
        for goals in ([sols[0]], sols[1:]) if len(sols) > 1 else ([sols[0]],):
            self._reseed()
            try:
                res = ap.planner.plan_qpos([ap.full(s) for s in goals], ap.full(start),
                                           time_step=self.dt, rrt_range=self.cfg.rrt_range,
                                           planning_time=self.cfg.planning_time)
            except RuntimeError as e:  # TOPP-RA could not time the path
                res = {"status": f"path could not be timed: {e}"}
            if res.get("status") == "Success":
                break
        if res.get("status") != "Success":
            return done("no_path", message=f"IK solved but no collision-free path: {res.get('status')}",
                        raw={"mplib_status": res.get("status")}, attempts=len(sols), **common)
        pos_raw = np.asarray(res["position"], float)
        if len(pos_raw) == 0:  # TOPP sampled nothing: a path too short to time
            pos = self._interpolate(ap, start, sols[0])
            if pos is None:
                return done("no_path", message="path too short to time-parametrise", **common)
            return done("success", positions=pos, message="short joint-space line", **common)
        # the goal actually reached is the IK solution nearest the path's end
        end = min(sols, key=lambda s: float(np.linalg.norm(s - pos_raw[-1])))
        pe, re = self._errors(arm, end, target)
        pos = self._resample(res["time"], pos_raw, start, end)
        return done("success", positions=pos, message="RRTConnect + TOPP-RA", position_error_m=pe,
                    rotation_error_rad=re, raw={"duration_s": float(res["duration"])})


def factory(cfg: dict) -> MplibPlanner:
    _import_mplib()
    return MplibPlanner(cfg)
