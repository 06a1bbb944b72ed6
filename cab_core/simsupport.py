"""Validation and start-up rules that every simulator backend applies alike, written once.

The :class:`cab_core.simulator.Simulator` contract says what a bad command raises, which object
names a scene may use, where the robot starts and what a snapshot must refuse; backends import these helpers instead of each
restating the rules (and drifting apart). Nothing here imports a simulator.
"""
from __future__ import annotations

import json

import numpy as np

from .embodiment import EmbodimentSpec
from .errors import BadCommand
from .scene import SceneSpec, as_pose
from .simulator import ROBOT, Contact, SimState


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
    np.savez(buf, layout=np.array(layout), contacts=np.array(json.dumps([[c.a, c.b, c.impulse, c.point]
                                                                          for c in contacts])), **arrays)
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
        contacts = [Contact(a, b, imp, None if pt is None else tuple(pt))
                    for a, b, imp, pt in json.loads(str(d.pop("contacts")))]
    except Exception as e:  # noqa: BLE001 (any decoding failure is a bad state)
        raise BadCommand(f"corrupt {backend} state: {e}") from None
    if saved_layout != layout:
        raise BadCommand("the state was saved from a different scene or robot")
    return d, contacts


def step_count_or_bad(n) -> int:
    """A physics step count: a non-negative integer (bools refused), or BadCommand."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise BadCommand(f"step count must be a non-negative integer, got {n!r}")
    return int(n)
