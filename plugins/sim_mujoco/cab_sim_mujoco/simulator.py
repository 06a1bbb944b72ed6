"""The MuJoCo backend of :class:`cab_core.contracts.simulator.Simulator`.

One ``MjModel`` / ``MjData`` pair per attempt, compiled from the MJCF that :mod:`.mjcf` writes from
the ``SceneSpec`` and the ``EmbodimentSpec``, and, unless ``render: false``, an OpenGL context
(:mod:`.gl`: EGL or OSMesa, chosen at launch, ``MUJOCO_GL`` respected) with one ``MjrContext``.

Options (the ``cfg`` dict of the plugin factory):

``render`` (bool, default true)
    Start OpenGL and render cameras. With ``false`` the world is physics only: camera poses,
    intrinsics and sizes still work, :meth:`render` raises ``RendererUnavailable``.
``timestep`` (float, default: the scene's, 1/250 s)
    Overrides ``SceneSpec.timestep``.
``physics`` (dict, default empty)
    Overrides of the declared physical parameters (:class:`.physics.PhysicsParams`, by name).

Conventions: poses are float64 ``[x, y, z, qw, qx, qy, qz]`` (MuJoCo quaternions are wxyz too).
Physics state is float64 and exact: ``save_state`` is ``mj_getState(mjSTATE_INTEGRATION)`` (time,
qpos, qvel, actuator and mocap state, controls, the solver's warm start) plus the drive targets and
the last step's contacts; restoring it makes the next steps bit-identical to the ones that followed
the save, in this build or in another build of the same scene and robot, and taking a snapshot
does not perturb the run.

Poses after a step: ``mj_step`` leaves link poses at the start of the step; they are brought up to
date (``mj_kinematics``, which touches nothing the next step reads) when first read after a step.
Contacts are those the last step solved, read lazily from ``MjData`` when first asked for.
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass

import numpy as np

from cab_core.contracts import simsupport as ss
from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.scene import SceneSpec
from cab_core.contracts.simulator import ROBOT, Contact, SimState, Simulator
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable, SimulatorError
from cab_core.geometry import pose_mul, quat_to_mat

from . import gl
from .mjcf import VISUAL_GROUP, MjcfWriter, Plan
from .physics import PhysicsParams

gl.forced_backend()  # before MuJoCo's import starts the OpenGL bindings MUJOCO_GL names
import mujoco  # noqa: E402

log = logging.getLogger(__name__)

BACKEND = "mujoco"
STATE_FORMAT = 1
_KNOWN_OPTIONS = {"render", "timestep", "physics", "name"}
_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION


@dataclass
class _Thing:
    """Where one object of the scene lives in the model."""
    kind: str  # static | dynamic | kinematic | articulation
    body: int  # body id (an articulation's root link)
    qadr: int = -1  # free joint: qpos address (7 values)
    dadr: int = -1  # free joint: dof address (6 values)
    mocap: int = -1  # mocap id (static, kinematic, fixed-root articulation)
    jq: np.ndarray | None = None  # articulation joints: qpos addresses
    jd: np.ndarray | None = None  # articulation joints: dof addresses
    links: dict[str, int] | None = None  # articulation: link -> body id


def scene_capacity(model) -> int:
    """The geoms an ``MjvScene`` of ``model`` holds: at least one for everything the scene update
    may draw with any visualisation option (each geom, site, camera, light, body, joint, actuator,
    sensor, skin, flex and its vertices, tendon wrap, equality constraint) and a margin for the
    decorations (contacts, perturbation, selection), where a fixed 20000 held 20 MiB a worker.
    :meth:`_Renderer.render` grows the scene should it ever be full."""
    counts = ("ngeom", "nsite", "ncam", "nlight", "nbody", "njnt", "nu", "nsensor", "nskin", "nflex",
              "nflexvert", "nwrap", "ntendon", "neq")
    return 2 * sum(int(getattr(model, n, 0)) for n in counts) + 1000


class _Renderer:
    """MuJoCo's OpenGL renderer for one model: scene, context and the options that hide collision
    geoms. Drawn into MuJoCo's off-screen framebuffer, read back, flipped to image rows."""

    def __init__(self, model, width: int, height: int):
        self.gl, self.info = gl.context(width, height)
        self.scene = mujoco.MjvScene(model, maxgeom=scene_capacity(model))
        with gl.current(self.gl):
            self.context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        self.option = mujoco.MjvOption()
        self.option.geomgroup[:] = 0
        self.option.geomgroup[VISUAL_GROUP] = 1
        self.camera = mujoco.MjvCamera()
        self.camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self.perturb = mujoco.MjvPerturb()

    def render(self, model, data, camera_id: int, width: int, height: int) -> np.ndarray:
        self.camera.fixedcamid = camera_id
        mujoco.mjv_updateScene(model, data, self.option, self.perturb, self.camera,
                               mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        while self.scene.ngeom >= self.scene.maxgeom:  # full: a geom may have been left out; never draw so
            self.scene = mujoco.MjvScene(model, maxgeom=2 * self.scene.maxgeom)
            mujoco.mjv_updateScene(model, data, self.option, self.perturb, self.camera,
                                   mujoco.mjtCatBit.mjCAT_ALL, self.scene)
        rect = mujoco.MjrRect(0, 0, width, height)
        rgb = np.empty((height, width, 3), dtype=np.uint8)
        with gl.current(self.gl):  # on whichever thread calls, released afterwards
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self.context)
            mujoco.mjr_render(rect, self.scene, self.context)
            mujoco.mjr_readPixels(rgb, None, rect, self.context)
        return np.ascontiguousarray(rgb[::-1])

    def free(self) -> None:
        with gl.current(self.gl):
            self.context.free()


class MujocoSimulator(ss.CameraAccessors, ss.LastStepContacts, Simulator):
    """MuJoCo (CPU physics; OpenGL rendering through EGL or OSMesa). Not thread-safe: one owner."""

    name = BACKEND

    def __init__(self, cfg: dict | None = None):
        cfg = ss.simulator_options(cfg, _KNOWN_OPTIONS, BACKEND)
        self._render_enabled = bool(cfg.get("render", True))
        self._timestep_override = ss.timestep_option(cfg, BACKEND)
        physics = cfg.get("physics") or {}
        if not hasattr(physics, "items"):
            raise ConfigError(f"mujoco physics must be a mapping of parameter overrides, got {physics!r}")
        self._phys = PhysicsParams.from_cfg(dict(physics))
        self._model = None
        self._closed = False

    # -- life cycle ---------------------------------------------------------------------------
    def build(self, scene: SceneSpec, embodiment: EmbodimentSpec) -> None:
        """Compile the world (see :mod:`.mjcf` for what is created), impose the bodies' masses,
        put the robot at home with its grippers open and its targets there, and start the
        renderer. Robot links carry no weight (gravity compensation), as on SAPIEN."""
        if self._model is not None or self._closed:
            raise SimulatorError("build() is called once per simulator")
        self._timestep = self._timestep_override or float(scene.timestep)
        plan = MjcfWriter(self._phys).write(scene, embodiment, self._timestep)
        try:
            model = mujoco.MjModel.from_xml_string(plan.xml)
        except ValueError as e:
            raise SimulatorError(f"MuJoCo could not compile the scene: {e}") from e
        self._model, self._data = model, mujoco.MjData(model)
        self._render_data = None  # pictures of render samples (render_samples), made on first use
        try:
            self._index(plan, scene, embodiment)
            self._renderer = None
            if self._render_enabled:
                w = max(c.spec.width for c in plan.cameras.values()) if plan.cameras else 64
                h = max(c.spec.height for c in plan.cameras.values()) if plan.cameras else 64
                self._renderer = _Renderer(model, w, h)
        except Exception:
            self.close()
            raise

    def _id(self, kind, name: str) -> int:
        return mujoco.mj_name2id(self._model, kind, name)

    def _index(self, plan: Plan, scene: SceneSpec, emb: EmbodimentSpec) -> None:
        """Impose masses and damping, find every part of the plan in the compiled model, set the
        start state; then derive everything else (``mj_forward``)."""
        m, d = self._model, self._data
        self._impose_mass_and_damping(plan)
        self._index_objects(plan, scene)
        self._index_robot(plan, emb)
        # contact attribution: body id -> reported name (the world's only geom is the ground)
        self._body_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, i) for i in range(m.nbody)]
        self._body_names[0] = "ground"
        self._cameras = plan.cameras
        self._camera_ids = {c: self._id(mujoco.mjtObj.mjOBJ_CAMERA, c) for c in plan.cameras}
        self._camera_bodies = {c: self._id(mujoco.mjtObj.mjOBJ_BODY, cam.body)
                               for c, cam in plan.cameras.items() if cam.body is not None}
        self._steps = 0
        self._contacts: list[Contact] | None = []
        mujoco.mj_forward(m, d)
        self._kinematics_current = True

    def _impose_mass_and_damping(self, plan: Plan) -> None:
        m, d = self._model, self._data
        body = mujoco.mjtObj.mjOBJ_BODY
        for name, mass in plan.masses.items():
            b = self._id(body, name)
            if m.body_mass[b] > 0:
                m.body_inertia[b] *= mass / m.body_mass[b]
            m.body_mass[b] = mass
        mujoco.mj_setConst(m, d)  # derived masses; it puts qpos back to qpos0, so it comes first
        for name, (linear, angular) in plan.damping.items():
            # PhysX's body damping scales velocity by 1 / (1 + dt c) each step; MuJoCo's implicit
            # joint damping D does the same when D = c x mass (and c x inertia for rotation)
            b, dof = self._id(body, name), int(m.jnt_dofadr[self._id(mujoco.mjtObj.mjOBJ_JOINT, name)])
            m.dof_damping[dof:dof + 3] = linear * m.body_mass[b]
            m.dof_damping[dof + 3:dof + 6] = angular * float(np.mean(m.body_inertia[b]))

    def _index_objects(self, plan: Plan, scene: SceneSpec) -> None:
        m, d = self._model, self._data
        body = lambda n: self._id(mujoco.mjtObj.mjOBJ_BODY, n)  # noqa: E731
        joint = lambda n: self._id(mujoco.mjtObj.mjOBJ_JOINT, n)  # noqa: E731
        self._things: dict[str, _Thing] = {}
        for name, kind in plan.bodies.items():
            t = _Thing(kind, body(name))
            if kind == "dynamic":
                j = joint(name)
                t.qadr, t.dadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
            else:
                t.mocap = int(m.body_mocapid[t.body])
            self._things[name] = t
        initial = {o.name: o.qpos for o in scene.articulations}
        for name, art in plan.articulations.items():
            t = _Thing("articulation", body(art.root), links={link: body(n) for link, n in art.links.items()})
            if art.fixed:
                t.mocap = int(m.body_mocapid[t.body])
            else:
                j = joint(f"{name}/root")
                t.qadr, t.dadr = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
            ids = [joint(n) for n in art.joints]
            t.jq = np.array([m.jnt_qposadr[j] for j in ids], dtype=np.int64)
            t.jd = np.array([m.jnt_dofadr[j] for j in ids], dtype=np.int64)
            if initial[name] is not None:
                d.qpos[t.jq] = ss.vector_or_bad(initial[name], len(t.jq), f"initial qpos of {name!r}")
            self._things[name] = t
        self._object_order = scene.names()

    def _index_robot(self, plan: Plan, emb: EmbodimentSpec) -> None:
        """Joint addresses and servo gains; the arms at home, grippers open, targets there."""
        m, d = self._model, self._data
        self._robot_links = {link: self._id(mujoco.mjtObj.mjOBJ_BODY, n) for link, n in plan.robot.links.items()}
        self._joint_names = emb.joint_order()
        jids = [self._id(mujoco.mjtObj.mjOBJ_JOINT, f"{ROBOT}/{n}") for n in plan.actuators]
        self._rq_all = np.array([m.jnt_qposadr[j] for j in jids], dtype=np.int64)
        self._rd_all = np.array([m.jnt_dofadr[j] for j in jids], dtype=np.int64)
        n = len(self._joint_names)
        self._rq, self._rd = self._rq_all[:n], self._rd_all[:n]
        self._kp = m.actuator_gainprm[:, 0].copy()
        self._kd = -m.actuator_biasprm[:, 2].copy()
        home = ss.start_joint_values(emb)
        start = np.array([home.get(nm, q) for nm, q in zip(self._joint_names, d.qpos[self._rq])])
        d.qpos[self._rq] = start
        for extra in plan.actuators[n:]:
            log.warning("robot joint %r is not in the embodiment's joint order; holding it at its start", extra)
        self._targets = np.zeros(n)
        self._vtargets = np.zeros(n)
        self._apply_targets(start)
        d.ctrl[n:] = d.qpos[self._rq_all[n:]]

    def close(self) -> None:
        """Release the renderer and the model. Idempotent."""
        self._closed = True
        if self._model is None:
            return
        r = getattr(self, "_renderer", None)
        if r is not None:
            try:
                r.free()
            except Exception:  # noqa: BLE001 (best effort at teardown)
                log.debug("freeing the MuJoCo render context failed", exc_info=True)
        self._renderer = None
        self._model = self._data = self._render_data = None

    def _live(self):
        return ss.live_or_error(self._model, self._closed)

    @property
    def timestep(self) -> float:
        self._live()
        return self._timestep

    def step(self, n: int = 1) -> None:
        n = ss.step_count_or_bad(n)
        self._live()
        if n == 0:
            return
        mujoco.mj_step(self._model, self._data, n)
        self._steps += n
        self._contacts = None
        self._kinematics_current = False

    def _kinematics(self):
        """MjData with link poses of the current qpos (recomputed once after steps or teleports)."""
        self._live()
        if not self._kinematics_current:
            mujoco.mj_kinematics(self._model, self._data)
            self._kinematics_current = True
        return self._data

    def _touched(self) -> None:
        """State changed without a step; contacts keep the last step's."""
        self._kinematics_current = False

    # -- robot --------------------------------------------------------------------------------
    @property
    def joint_names(self) -> list[str]:
        self._live()
        return list(self._joint_names)

    def get_qpos(self) -> np.ndarray:
        self._live()
        return self._data.qpos[self._rq].copy()

    def get_qvel(self) -> np.ndarray:
        self._live()
        return self._data.qvel[self._rd].copy()

    def set_qpos(self, qpos: np.ndarray) -> None:
        self._live()
        q = ss.vector_or_bad(qpos, len(self._joint_names), "robot qpos")
        self._data.qpos[self._rq] = q
        self._data.qvel[self._rd_all] = 0.0
        self._apply_targets(q)
        self._touched()

    def set_drive_targets(self, targets: np.ndarray, velocities: np.ndarray | None = None) -> None:
        self._live()
        t = ss.vector_or_bad(targets, len(self._joint_names), "drive targets")
        v = None if velocities is None else ss.vector_or_bad(velocities, len(self._joint_names),
                                                            "drive velocity targets")
        self._apply_targets(t, v)

    def _apply_targets(self, t: np.ndarray, v: np.ndarray | None = None) -> None:
        """The servo force is kp (ctrl - q) - kd qdot; ctrl = q* + (kd / kp) v* makes it
        kp (q* - q) + kd (v* - qdot), PhysX's drive with a velocity target."""
        v = np.zeros(len(t)) if v is None else v
        n = len(t)
        self._data.ctrl[:n] = t + self._kd[:n] / self._kp[:n] * v
        self._targets[:] = t
        self._vtargets[:] = v

    def get_drive_targets(self) -> np.ndarray:
        self._live()
        return self._targets.copy()

    def _body_pose(self, b: int) -> np.ndarray:
        d = self._kinematics()
        return np.concatenate([d.xpos[b], d.xquat[b]])

    def get_link_pose(self, link: str) -> np.ndarray:
        self._live()
        return self._body_pose(ss.robot_link_or_bad(self._robot_links, link))

    # -- objects ------------------------------------------------------------------------------
    def object_names(self) -> list[str]:
        self._live()
        return list(self._object_order)

    def _thing(self, name: str) -> _Thing:
        self._live()
        t = self._things.get(name) if isinstance(name, str) else None
        if t is None:
            raise BadCommand(f"unknown object {name!r}")
        return t

    def get_object_pose(self, name: str) -> np.ndarray:
        t = self._thing(name)
        d = self._data
        if t.qadr >= 0:
            return d.qpos[t.qadr:t.qadr + 7].copy()
        return np.concatenate([d.mocap_pos[t.mocap], d.mocap_quat[t.mocap]])

    def set_object_pose(self, name: str, pose) -> None:
        """Teleport a body (or an articulated object's root) and zero its velocity (and, for an
        articulated object, its joints' velocities)."""
        t = self._thing(name)
        p = np.asarray(ss.pose_or_bad(pose))
        d = self._data
        if t.qadr >= 0:
            d.qpos[t.qadr:t.qadr + 7] = p
            d.qvel[t.dadr:t.dadr + 6] = 0.0
        else:
            d.mocap_pos[t.mocap] = p[:3]
            d.mocap_quat[t.mocap] = p[3:]
        if t.jd is not None:
            d.qvel[t.jd] = 0.0
        self._touched()

    def get_object_velocity(self, name: str) -> np.ndarray:
        """[v, w] in the world frame: the velocity of the centre of mass (as PhysX and Bullet
        report it) and the angular velocity. MuJoCo's free joint holds the velocity of the body's
        origin, and the angular part in the body frame; both are converted."""
        t = self._thing(name)
        if t.dadr < 0:
            return np.zeros(6)
        d = self._data
        v = d.qvel[t.dadr:t.dadr + 6]
        r = quat_to_mat(d.qpos[t.qadr + 3:t.qadr + 7])
        w = r @ v[3:]
        return np.concatenate([v[:3] + np.cross(w, r @ self._model.body_ipos[t.body]), w])

    def get_object_qpos(self, name: str) -> np.ndarray:
        t = self._thing(name)
        return np.zeros(0) if t.jq is None else self._data.qpos[t.jq].copy()

    def set_object_qpos(self, name: str, qpos) -> None:
        """Set an articulated object's joints (and zero their velocities)."""
        t = self._thing(name)
        if t.jq is None:
            raise BadCommand(f"{name!r} is a rigid body; it has no joints")
        q = ss.vector_or_bad(qpos, len(t.jq), f"qpos of {name!r}")
        self._data.qpos[t.jq] = q
        self._data.qvel[t.jd] = 0.0
        self._touched()

    def get_object_link_names(self, name: str) -> list[str]:
        self._live()
        t = self._things.get(name)
        return list(t.links) if t is not None and t.links else []

    def get_object_link_pose(self, name: str, link: str) -> np.ndarray:
        t = self._thing(name)
        return self._body_pose(ss.object_link_or_bad(t.links or {}, name, link))

    # -- contacts -----------------------------------------------------------------------------
    def _compute_contacts(self) -> list[Contact]:
        """Impulse = sum over the pair's contact points of |force| x timestep (N*s), force = normal
        plus friction; point = mean position of the points that carried force."""
        m, d = self._model, self._data
        acc = ss.PairContacts()
        if d.ncon == 0:
            return []
        geom_body = m.geom_bodyid
        names = self._body_names
        force = np.zeros(6)
        con = d.contact
        for i in range(d.ncon):
            if con.efc_address[i] < 0:
                continue
            mujoco.mj_contactForce(m, d, i, force)
            f = math.sqrt(force[0] * force[0] + force[1] * force[1] + force[2] * force[2])
            if f <= 0.0:
                continue
            x, y, z = con.pos[i]
            acc.add(names[geom_body[con.geom1[i]]], names[geom_body[con.geom2[i]]], f, x, y, z)
        return acc.contacts(self._timestep)

    # -- cameras ------------------------------------------------------------------------------
    def camera_pose(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if cam.body is None:
            return np.asarray(cam.local, dtype=float)
        return pose_mul(self._body_pose(self._camera_bodies[name]), cam.local)

    def render(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if self._renderer is None:
            raise RendererUnavailable("this MuJoCo simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        d = self._kinematics()
        mujoco.mj_camlight(self._model, d)
        return self._renderer.render(self._model, d, self._camera_ids[name], cam.spec.width, cam.spec.height)

    def render_sample(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Copies of ``qpos``, ``mocap_pos`` and ``mocap_quat``: every pose the renderer draws
        follows from them (``mj_kinematics``)."""
        self._live()
        if self._renderer is None:
            return None
        d = self._data
        return d.qpos.copy(), d.mocap_pos.copy(), d.mocap_quat.copy()

    def render_samples(self, name, samples, emit) -> None:
        """Each sample goes into a second ``MjData`` of the model, used for pictures only (poses
        from ``mj_kinematics`` and ``mj_camlight``, as :meth:`render` computes them); the
        attempt's ``MjData`` is not touched."""
        cam = self._camera(name)
        if self._renderer is None:
            raise RendererUnavailable("this MuJoCo simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        m = self._model
        if self._render_data is None:
            self._render_data = mujoco.MjData(m)
        d = self._render_data
        cid, w, h = self._camera_ids[name], cam.spec.width, cam.spec.height
        for sample in samples:
            qpos, mocap_pos, mocap_quat = sample
            if qpos.shape != d.qpos.shape or mocap_pos.shape != d.mocap_pos.shape:
                raise BadCommand("a render sample of another world")
            d.qpos[:], d.mocap_pos[:], d.mocap_quat[:] = qpos, mocap_pos, mocap_quat
            mujoco.mj_kinematics(m, d)
            mujoco.mj_camlight(m, d)
            emit(self._renderer.render(m, d, cid, w, h))

    # -- state --------------------------------------------------------------------------------
    def _layout(self) -> str:
        m = self._model
        return json.dumps({"format": STATE_FORMAT, "nq": m.nq, "nv": m.nv, "nu": m.nu, "nmocap": m.nmocap,
                           "objects": [(n, t.kind) for n, t in self._things.items()],
                           "joints": self._joint_names})

    def save_state(self) -> SimState:
        """Snapshot: ``mj_getState(mjSTATE_INTEGRATION)`` (float64), drive targets, step count and
        the last step's contacts, as an ``.npz`` archive (no pickle)."""
        m = self._live()
        state = np.empty(mujoco.mj_stateSize(m, _STATE_SPEC))
        mujoco.mj_getState(m, self._data, state, _STATE_SPEC)
        d = dict(state=state, targets=self._targets.copy(), vtargets=self._vtargets.copy(),
                 steps=np.array(self._steps, np.int64))
        return ss.pack_state(BACKEND, self._layout(), d, self.get_contacts())

    def restore_state(self, state: SimState) -> None:
        """Restore a snapshot of this world (or of another build of the same scene and robot)."""
        m = self._live()
        d, contacts = ss.unpack_state(state, BACKEND, self._layout())
        if d["state"].shape != (mujoco.mj_stateSize(m, _STATE_SPEC),):
            raise BadCommand("the state was saved from a different scene or robot")
        mujoco.mj_setState(m, self._data, d["state"], _STATE_SPEC)
        self._targets[:] = d["targets"]
        self._vtargets[:] = d["vtargets"]
        self._steps = int(d["steps"])
        self._contacts = contacts
        self._touched()

    # -- provenance ---------------------------------------------------------------------------
    def versions(self) -> dict[str, str]:
        self._live()
        out = {"simulator": BACKEND, "mujoco": mujoco.__version__, "mujoco_lib": mujoco.mj_versionString(),
               "timestep": repr(self._timestep), "render": "on" if self._renderer is not None else "off",
               "physics": json.dumps(self._phys.as_dict(), sort_keys=True)}
        if self._renderer is not None:
            out.update(gl.describe(self._renderer.info))
        return out

    # -- extras (not part of the contract) ----------------------------------------------------
    @property
    def steps(self) -> int:
        """Physics steps taken since build (restored with a snapshot)."""
        self._live()
        return self._steps
