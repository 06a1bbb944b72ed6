"""What tool handlers see of the host: the world (through contracts), observations (and drawing on
them), the clock.

Handlers must never put privileged data (object names or poses, verifier state) in a payload.
"""
from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from cab_core.errors import ObservationUnavailable, SimulatorError, ToolArgumentError
from cab_core.geometry import extrinsic_from_pose
from cab_core.tools.models import CAMERAS
from cab_core.tools.overlay import Canvas

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.embodiment import EmbodimentSpec
    from cab_core.contracts.planner import Planner
    from cab_core.contracts.simulator import Simulator


@dataclass
class Observation:
    obs_id: str
    camera: str
    image: np.ndarray  # uint8 HxWx3
    K: np.ndarray  # 3x3
    E: np.ndarray  # 3x4 world->camera (p_cam = R p_world + t), OpenCV axes
    tick: int
    physics_step: int
    annotation: dict[str, Any] = field(default_factory=dict)
    source_obs_id: str | None = None  # for annotated copies (draw_marks, previews)

    @property
    def size_hw(self) -> list[int]:
        return [int(self.image.shape[0]), int(self.image.shape[1])]

    def snapshot(self) -> dict:
        """The ``cam_pose_snapshot`` block of an Observation result."""
        return {
            "available": True,
            "K": np.round(self.K, 6).tolist(),
            "E": np.round(self.E, 6).tolist(),
            "size_hw": self.size_hw,
            "freshness": "captured_at_tick",
            "read_failures": 0,
            "convention": "E = [R|t] maps world to camera (p_cam = R p_world + t); camera +x right, +y down, +z forward; K pinhole, no distortion",
        }

    def summary(self) -> dict:
        """The JSON part of an observation as the agent sees it (the image goes separately)."""
        out = {"obs_id": self.obs_id, "camera": self.camera, "tick": self.tick,
               "cam_pose_snapshot": self.snapshot(), "image": {"attached": True, "size_hw": self.size_hw}}
        if self.annotation:
            out["annotation"] = self.annotation
        if self.source_obs_id:
            out["source_obs_id"] = self.source_obs_id
        return out


class ObservationStore:
    """Every image the agent was shown, by id. ``on_add`` lets the recorder persist each one."""

    def __init__(self, on_add: Callable[[Observation], object] | None = None):
        self._obs: dict[str, Observation] = {}
        self._counter = itertools.count(1)
        self._on_add = on_add

    def add(self, camera: str, image: np.ndarray, K: np.ndarray, E: np.ndarray, tick: int, physics_step: int,
            annotation: dict | None = None, source_obs_id: str | None = None) -> Observation:
        obs_id = f"obs_{next(self._counter):04d}"
        o = Observation(obs_id, camera, np.ascontiguousarray(image, dtype=np.uint8), np.asarray(K, float),
                        np.asarray(E, float), tick, physics_step, annotation or {}, source_obs_id)
        self._obs[obs_id] = o
        if self._on_add:
            self._on_add(o)
        return o

    def get(self, obs_id: str) -> Observation:
        try:
            return self._obs[obs_id]
        except KeyError:
            raise ToolArgumentError(f"unknown obs_id {obs_id!r}") from None

    def __contains__(self, obs_id: str) -> bool:
        return obs_id in self._obs

    def latest_tick(self) -> int:
        return max((o.tick for o in self._obs.values()), default=-1)


class RobotContext:
    """The host side of the robot API for one attempt.

    ``clock`` is the episode's step clock: ``clock.step(n)`` advances physics, charges simulated
    time, polls latches and feeds the video; ``clock.steps`` is the number of physics steps so far.
    """

    def __init__(self, sim: Simulator, planner: Planner, emb: EmbodimentSpec, clock: Any,
                 obs: ObservationStore, params: dict | None = None):
        self.sim = sim
        self.planner = planner
        self.emb = emb
        self.clock = clock
        self.obs = obs
        self.params = params or {}
        self.tick = 0  # advances only when an action actuated the robot
        self.gripper_cmd: dict[str, float] = {a: 1.0 for a in emb.arms}  # commanded, 1 = open
        self.pairs: dict[str, dict] = {}  # capture_motion_pair records by pair_id
        self._action_counter = itertools.count(1)
        self._pair_counter = itertools.count(1)
        self._joint_idx: dict[tuple[str, ...], np.ndarray] = {}

    # -- ids ----------------------------------------------------------------------------------
    def next_action_id(self) -> str:
        return f"act_{next(self._action_counter):04d}"

    def next_pair_id(self) -> str:
        return f"pair_{next(self._pair_counter):03d}"

    # -- robot readings -----------------------------------------------------------------------
    def arm(self, name: str):
        try:
            return self.emb.arms[name]
        except KeyError:
            raise ToolArgumentError(f"arm must be one of {sorted(self.emb.arms)}, got {name!r}") from None

    def tcp_pose(self, arm: str) -> np.ndarray:
        return self.sim.get_link_pose(self.arm(arm).tcp_link)

    def ee_pose(self, arm: str) -> np.ndarray:
        return self.sim.get_link_pose(self.arm(arm).ee_link)

    def joint_indices(self, joints) -> np.ndarray:
        """Positions of ``joints`` in the simulator's ``joint_names`` (looked up once a list)."""
        key = tuple(joints)
        idx = self._joint_idx.get(key)
        if idx is None:
            names = self.sim.joint_names
            idx = self._joint_idx[key] = np.array([names.index(j) for j in key], dtype=np.intp)
        return idx

    def arm_qpos(self, arm: str) -> np.ndarray:
        return self.sim.get_qpos()[self.joint_indices(self.arm(arm).joints)]

    def finger_qpos(self, arm: str) -> np.ndarray:
        return self.sim.get_qpos()[self.joint_indices(self.arm(arm).gripper.joints)]

    def finger_gap(self, arm: str) -> float:
        g = self.arm(arm).gripper
        return float(g.gap_at_zero_m + g.gap_per_unit * float(np.sum(self.finger_qpos(arm))))

    def finger_link_poses(self, arm: str) -> dict[str, np.ndarray]:
        return {link: self.sim.get_link_pose(link) for link in self.arm(arm).gripper.finger_links}

    # -- cameras ------------------------------------------------------------------------------
    def camera_K(self, camera: str) -> np.ndarray:
        return self.sim.camera_intrinsics(camera)

    def camera_E(self, camera: str) -> np.ndarray:
        return extrinsic_from_pose(self.sim.camera_pose(camera))

    def _known_camera(self, camera: str) -> None:
        if camera not in CAMERAS:
            raise ToolArgumentError(f"camera must be one of {list(CAMERAS)}, got {camera!r}")

    def capture(self, camera: str, annotation: dict | None = None) -> Observation:
        self._known_camera(camera)
        try:
            img = self.sim.render(camera)
        except SimulatorError as e:  # RendererUnavailable included: a read failure, not a crash
            raise ObservationUnavailable(f"{camera}: {e}") from e
        return self.obs.add(camera, img, self.camera_K(camera), self.camera_E(camera), self.tick,
                            self.clock.steps, annotation)

    def capture_annotated(self, camera: str, painter: Callable[[Canvas, np.ndarray, np.ndarray], dict]) -> Observation:
        """Render ``camera`` now, let ``painter(canvas, K, E)`` draw and return the annotation, store
        the drawn image as one new observation."""
        self._known_camera(camera)
        img = self.sim.render(camera)
        K, E = np.asarray(self.camera_K(camera), float), np.asarray(self.camera_E(camera), float)
        canvas = Canvas(img)
        annotation = painter(canvas, K, E)
        return self.obs.add(camera, canvas.image(), K, E, self.tick, self.clock.steps, annotation)

    def annotated_copy(self, obs: Observation, painter: Callable[[Canvas], dict]) -> Observation:
        """A new observation: ``obs``'s image with drawings, same camera, calibration and tick."""
        canvas = Canvas(obs.image)
        annotation = painter(canvas)
        return self.obs.add(obs.camera, canvas.image(), obs.K, obs.E, obs.tick, obs.physics_step, annotation,
                            source_obs_id=obs.obs_id)
