"""Validation, start-up rules and accessors that every simulator backend applies alike, written once.

The :class:`cab_core.contracts.simulator.Simulator` contract says what a bad command or option raises, which
object names a scene may use, where the robot starts, what a snapshot must refuse, how cameras are
looked up and how contacts are summed per body pair; backends import these helpers (and the two
small mixins :class:`CameraAccessors` and :class:`LastStepContacts`) instead of each restating the
rules and drifting apart. Nothing here imports a simulator.
"""
from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

import numpy as np

from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.scene import CameraSpec, SceneSpec, as_pose
from cab_core.contracts.simulator import ROBOT, Contact, SimState
from cab_core.errors import BadCommand, ConfigError, SimulatorError
from cab_core.geometry import intrinsics

T = TypeVar("T")


def pose_or_bad(pose) -> tuple[float, ...]:
    """A normalised 7-vector pose, or BadCommand saying what is wrong with it."""
    try:
        return as_pose(pose)
    except (ValueError, TypeError) as e:
        raise BadCommand(str(e)) from None


def vector_or_bad(values, n: int, what: str) -> np.ndarray:
    """``n`` finite float64 values, or BadCommand naming ``what`` was malformed."""
    try:
        a = np.asarray(values, dtype=np.float64)
    except (ValueError, TypeError) as e:
        raise BadCommand(f"{what}: expected {n} numbers, got {values!r} ({e})") from None
    if a.shape != (n,):
        raise BadCommand(f"{what}: expected shape ({n},), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise BadCommand(f"{what}: non-finite value in {a.tolist()}")
    return a


def check_object_names(scene: SceneSpec) -> None:
    """Object names are unique, non-empty, without '/', and not 'robot' or 'ground' (contact
    reports name links ``<object>/<link>`` and ``robot/<link>``, and the ground ``ground``)."""
    seen: set[str] = set()
    for name in scene.names():
        if not name or "/" in name or name in (ROBOT, "ground") or name in seen:
            raise BadCommand(f"invalid or duplicate object name {name!r} (names are unique, "
                             f"non-empty, without '/', and not 'robot' or 'ground')")
        seen.add(name)


def start_joint_values(emb: EmbodimentSpec) -> dict[str, float]:
    """Where each driven joint starts: every arm at its ``home_qpos``, its gripper open unless the
    home values include the gripper joints."""
    out: dict[str, float] = {}
    for arm in emb.arms.values():
        home = tuple(arm.home_qpos)
        if len(home) == len(arm.joints):
            values = list(home) + [arm.gripper.open_target] * len(arm.gripper.joints)
        elif len(home) == len(arm.joints) + len(arm.gripper.joints):
            values = list(home)
        else:
            raise BadCommand(f"arm {arm.name!r}: home_qpos has {len(home)} values for {len(arm.joints)} joints")
        out.update(zip(list(arm.joints) + list(arm.gripper.joints), (float(v) for v in values)))
    return out


def pack_state(backend: str, layout: str, arrays: dict[str, np.ndarray], contacts: list[Contact]) -> SimState:
    """A snapshot as an ``.npz`` archive (no pickle): the backend's arrays, its world ``layout``
    (checked on restore) and the last step's contacts."""
    import io

    buf = io.BytesIO()
    members: dict[str, Any] = {"layout": np.array(layout), "keys": np.array(json.dumps(sorted(arrays))),
                               "contacts": np.array(json.dumps([[c.a, c.b, c.impulse, c.point] for c in contacts])),
                               **arrays}
    np.savez(buf, **members)
    return SimState(backend=backend, data=buf.getvalue())


def unpack_state(state, backend: str, layout: str) -> tuple[dict[str, np.ndarray], list[Contact]]:
    """The arrays and contacts of a :func:`pack_state` snapshot; BadCommand if it is not this
    backend's, cannot be decoded, or was saved from a different world ``layout``."""
    import io

    if not isinstance(state, SimState) or state.backend != backend:
        raise BadCommand(f"not a {backend} state: {getattr(state, 'backend', type(state).__name__)!r}")
    try:
        with np.load(io.BytesIO(state.data), allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
        saved_layout = str(d.pop("layout"))
        keys = json.loads(str(d.pop("keys")))
        contacts = [Contact(a, b, imp, None if pt is None else tuple(pt))
                    for a, b, imp, pt in json.loads(str(d.pop("contacts")))]
    except Exception as e:  # noqa: BLE001 (any decoding failure is a bad state)
        raise BadCommand(f"corrupt {backend} state: {e!r}") from None
    missing = sorted(set(keys) - set(d))
    if missing:
        raise BadCommand(f"corrupt {backend} state: missing {missing}")
    if saved_layout != layout:
        raise BadCommand("the state was saved from a different scene or robot")
    return d, contacts


def step_count_or_bad(n) -> int:
    """A physics step count: a non-negative integer (bools refused), or BadCommand."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise BadCommand(f"step count must be a non-negative integer, got {n!r}")
    return int(n)


def check_camera_spec(spec: CameraSpec, taken) -> None:
    """BadCommand if a camera's name is already in ``taken`` or its size or field of view is
    impossible (sizes positive, vertical field of view strictly between 0 and 180 degrees)."""
    if spec.name in taken:
        raise BadCommand(f"duplicate camera name {spec.name!r}")
    if spec.width <= 0 or spec.height <= 0 or not 0 < spec.fovy_deg < 180:
        raise BadCommand(f"camera {spec.name!r}: bad size or field of view")


def camera_mount(spec: CameraSpec, links: Mapping[str, T]) -> T | None:
    """The robot link (from ``links``, by name) a camera is mounted on, None for a fixed camera,
    or BadCommand if the camera names a link the robot does not have."""
    if spec.mount_link is None:
        return None
    link = links.get(spec.mount_link)
    if link is None:
        raise BadCommand(f"camera {spec.name!r}: mount link {spec.mount_link!r} is not a robot link")
    return link


class CameraAccessors:
    """The contract's camera look-ups, for a backend that keeps ``self._cameras`` (camera name ->
    an object with the camera's ``spec``) and raises from ``self._live()`` once closed. Pose and
    rendering stay with the backend: only they differ between simulators."""

    _cameras: dict
    _live: Callable[[], None]  # the backend's: raises once the simulator is closed

    def _camera(self, name: str):
        """The backend's record of camera ``name``, or BadCommand."""
        self._live()
        cam = self._cameras.get(name) if isinstance(name, str) else None
        if cam is None:
            raise BadCommand(f"unknown camera {name!r}")
        return cam

    def camera_names(self) -> list[str]:
        self._live()
        return list(self._cameras)

    def camera_intrinsics(self, name: str) -> np.ndarray:
        s = self._camera(name).spec
        return intrinsics(int(s.width), int(s.height), float(s.fovy_deg))

    def camera_size(self, name: str) -> tuple[int, int]:
        s = self._camera(name).spec
        return int(s.height), int(s.width)


class LastStepContacts:
    """``get_contacts`` for a backend that reads its engine's contacts of the last step on the
    first call after that step (``self._compute_contacts()``) and keeps them in ``self._contacts``
    (None: not read yet), so that stepping costs nothing extra."""

    _contacts: list[Contact] | None
    _live: Callable[[], None]  # the backend's: raises once the simulator is closed
    _compute_contacts: Callable[[], list[Contact]]  # the backend's: the last step's contacts from its engine

    def get_contacts(self) -> list[Contact]:
        """One entry per body pair in contact during the last step, names sorted within the pair,
        pairs sorted (see the backend's ``_compute_contacts`` for its impulse and point)."""
        self._live()
        if self._contacts is None:
            self._contacts = self._compute_contacts()
        return list(self._contacts)


class PairContacts:
    """Sums contact points per pair of named bodies: impulse, position sum and point count; the
    result is one :class:`Contact` a pair at the mean position. A pair with an unnamed body
    (None) or a body touching itself is left out."""

    def __init__(self) -> None:
        self._acc: dict[tuple[str, str], list] = {}

    def add(self, n0: str | None, n1: str | None, impulse, x, y, z, k: int = 1) -> None:
        """Add ``k`` points between ``n0`` and ``n1`` carrying ``impulse`` whose positions sum to
        ``(x, y, z)``."""
        if n0 is None or n1 is None or n0 == n1:
            return
        key = (n0, n1) if n0 <= n1 else (n1, n0)
        e = self._acc.get(key)
        if e is None:
            self._acc[key] = [impulse, x, y, z, k]
        else:
            e[0] += impulse
            e[1] += x
            e[2] += y
            e[3] += z
            e[4] += k

    def contacts(self, scale: float = 1.0) -> list[Contact]:
        """The pairs, sorted, with their summed impulse times ``scale`` (a timestep where the sums
        are forces) and their mean point."""
        return [Contact(a, b, float(e[0] * scale), (float(e[1] / e[4]), float(e[2] / e[4]), float(e[3] / e[4])))
                for (a, b), e in sorted(self._acc.items())]


#: keys of a simulator's config that the core reads, not the backend: its per-slot memory in a sweep
#: (cab_core.conf.in_flight)
CORE_SIM_KEYS = frozenset({"slot_memory_mb"})


def simulator_options(cfg, known: set[str], backend: str) -> dict:
    """A backend's option dict (None: no options), or ConfigError naming the options it does not
    know; keys starting with ``_`` are the caller's private ones and pass, and so do the keys the core
    reads of every simulator's config (:data:`CORE_SIM_KEYS`)."""
    cfg = dict(cfg or {})
    unknown = sorted(k for k in cfg if k not in known and k not in CORE_SIM_KEYS and not str(k).startswith("_"))
    if unknown:
        raise ConfigError(f"unknown {backend} simulator option(s) {unknown}; known: {sorted(known)}")
    return cfg


def timestep_option(cfg: dict, backend: str) -> float | None:
    """The ``timestep`` option in seconds (None: the scene's), or ConfigError unless it is a
    positive number (bools refused)."""
    ts = cfg.get("timestep")
    if ts is not None and (isinstance(ts, bool) or not isinstance(ts, (int, float)) or not ts > 0):
        raise ConfigError(f"{backend} timestep must be a positive number, got {ts!r}")
    return None if ts is None else float(ts)


def live_or_error(handle: T | None, closed: bool) -> T:
    """A backend's engine handle while its world exists, else SimulatorError saying whether the
    simulator was closed or never built."""
    if handle is None:
        raise SimulatorError("the simulator is closed" if closed else "build() was not called")
    return handle


def robot_link_or_bad(links: Mapping[str, T], link) -> T:
    """The robot link named ``link`` in ``links``, by its own name or as ``robot/<link>`` (the
    form contact reports use), or BadCommand."""
    found = links.get(link) if isinstance(link, str) else None
    if found is None and isinstance(link, str) and link.startswith(ROBOT + "/"):
        found = links.get(link[len(ROBOT) + 1:])
    if found is None:
        raise BadCommand(f"unknown robot link {link!r}")
    return found


def object_link_or_bad(links: Mapping[str, T], name: str, link) -> T:
    """Link ``link`` of object ``name`` from that object's ``links``, or BadCommand."""
    found = links.get(link) if isinstance(link, str) else None
    if found is None:
        raise BadCommand(f"unknown link {link!r} of object {name!r}")
    return found
