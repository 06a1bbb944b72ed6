"""The PyBullet backend of :class:`cab_core.contracts.simulator.Simulator`.

One DIRECT physics client per simulator (several simulators live side by side in one process; every
call names its client). Built once from a ``SceneSpec`` plus an ``EmbodimentSpec``, the same
description the SAPIEN backend builds from; see :meth:`PybulletSimulator.build`.

Options (the ``cfg`` dict of the plugin factory; ``conf/sim/pybullet.yaml`` sets them):

``render`` (bool, default true)
    Create visual shapes and render cameras. With ``false``, camera poses, intrinsics and sizes still
    work and :meth:`render` raises ``RendererUnavailable``.
``renderer`` (``auto`` | ``tiny`` | ``egl``, default ``auto``)
    See :mod:`cab_sim_pybullet.renderer`: TinyRenderer on the CPU, the EGL plugin with a GPU.
``timestep`` (float, default: the scene's, 1/250 s)
    Overrides ``SceneSpec.timestep``.
``physics`` (dict)
    Physical parameters where Bullet needs a value that PhysX does not, or models a quantity
    differently; keys and defaults in :data:`PHYSICS_DEFAULTS`, each documented there.

Conventions: poses are float64 ``[x, y, z, qw, qx, qy, qz]`` (PyBullet's quaternions are xyzw and
its base pose is the centre-of-mass frame; both are converted here). Cameras: computed from the
mount link and the OpenCV-axes spec, rendered with a projection built from K (1 px agreement with
SAPIEN's pinhole model by construction).

Textures (``Material.texture``): a textured box, sphere, cylinder or capsule is drawn as the
triangle mesh :func:`cab_core.contracts.texturing.uv_mesh` writes (a ``GEOM_MESH`` visual shape;
texture coordinates in tiles of 0.3 m of surface: the image repeats every 0.3 m on every face, see
there), the image loaded with ``loadTexture`` and put on that visual shape with
``changeVisualShape(textureUniqueId=...)`` (a capsule is then one mesh, not split into a cylinder
and two spheres). TinyRenderer multiplies the texture by the shape's colour, which is white (alpha
kept): the image replaces the plain colour; it samples the nearest texel and wraps coordinates
beyond 0..1 (the EGL renderer repeats too). Meshes keep their plain colour. Visual shapes only:
the collision shapes, links and masses are as without textures. ``resetSimulation`` drops the
client's textures, so every (re)build loads them again. The image is checked at every build,
physics-only ones included: a missing or unreadable file is a ``SimulatorError`` naming it.

Snapshots: ``save_state`` records every multibody's base pose and velocity and joint positions and
velocities exactly as Bullet holds them (float64), the drive targets, the step count and the last
step's contacts. Restoring resets the physics client and rebuilds the world from the same
description before writing the state, so no contact cache (Bullet's persistent manifolds and their
warm-start impulses) survives from a different history: stepping after a restore depends on the
snapshot only. ``save_state`` writes its snapshot back the same way, so "save, step" and "restore,
step" replay alike, in this simulator or in another build. The price: a snapshot perturbs the run
it is taken from (the dropped warm-start caches), identically on every run that takes it; and a
restore (and a save) costs a rebuild: 0.2-0.5 s for an aloha scene on
a 2-core CPU (the episode itself takes no snapshots).
"""
from __future__ import annotations

import importlib.metadata
import json
import logging
import math
import os
from dataclasses import dataclass, field, replace

import numpy as np

from ._quiet import c_output_silenced

with c_output_silenced():  # its build-time banner
    import pybullet
from pybullet_utils.bullet_client import BulletClient

from cab_core.contracts import simsupport as ss
from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.scene import Box, CameraSpec, Capsule, Cylinder, Material, Mesh, SceneSpec, Sphere
from cab_core.contracts.simulator import ROBOT, Contact, SimState, Simulator
from cab_core.contracts.texturing import texture_image, textured, uv_mesh
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable, SimulatorError
from cab_core.geometry import intrinsics, mat_to_quat, pose_inv, pose_mul

from . import massprops
from . import renderer as _renderer

log = logging.getLogger(__name__)

BACKEND = "pybullet"
STATE_FORMAT = 1
_KNOWN_OPTIONS = {"render", "renderer", "timestep", "physics", "name"}

PHYSICS_DEFAULTS: dict[str, float] = {
    # Constraint-solver iterations per step (Bullet's sequential impulse solver). Measured on the
    # oracles: at 50 a finger pad sinks 3-8 mm into a squeezed block, which tilts and can drop out
    # of the grasp (blocks_ranking_size: 6 of 10 perturbed runs, 17 of 20 held-out seeds); at 150
    # the pads stay within 1 mm and every such run holds.
    "solver_iterations": 150.0,
    # Squeeze of each gripper finger on a grasped object (N). Bullet's joint motor pushes with at
    # most this force once the fingers are blocked; PhysX's drive pushes with stiffness * error.
    "gripper_force_n": 40.0,
    # Upper bound of an arm joint motor (N m) where the URDF declares no effort limit.
    "arm_force_nm": 200.0,
    # Drive response: a joint motor asks for v = v_target + (stiffness / damping) * error each
    # step, the massless limit of the PhysX drive force stiffness * error + damping * (v_t - v).
    # This factor scales the stiffness / damping ratio.
    "drive_rate_scale": 1.0,
    # Rolling resistance (m: the lever arm of the resisting torque per newton of normal force), on
    # every surface. PhysX's exact cylinders rest on a contact patch; Bullet's rest on a line whose
    # contact noise sets a free cylinder rolling by itself within seconds (measured: a roller on a
    # table drifts 0.1 m in 4 s with none, stays put with 0.0005).
    "rolling_friction_m": 0.001,
    # Torsional friction (m: resisting torque per newton of normal force about the contact
    # normal), on every surface. PhysX's friction patches resist twisting over their area; a
    # Bullet contact point does not. About (2/3) mu r for a patch of radius r ~ 6 mm. Measured on
    # the oracles: at 0.001 a small block carried in one gripper swings out of it
    # (blocks_ranking_size); at 0.003 the block held for a handover resists the other hand's
    # fingers so stiffly that they shove it aside (handover_block); 0.002 does both tasks.
    "spinning_friction_m": 0.002,
    # Diffuse and specular coefficients of TinyRenderer's light (the ambient one comes from the scene).
    "light_diffuse": 0.6,
    "light_specular": 0.0,
}
# Friction: PhysX combines two materials' coefficients by their average, Bullet by their product.
# Each material gets sqrt(mu) here (mu = mean of its static and dynamic coefficients), so a pair
# combines to the geometric mean of the two, which equals PhysX's average for equal coefficients.


def _xyzw(q) -> list[float]:
    return [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


def _pose_from_bullet(pos, orn) -> np.ndarray:
    return np.array([pos[0], pos[1], pos[2], orn[3], orn[0], orn[1], orn[2]], dtype=float)


def _bullet_friction(m: Material) -> float:
    return math.sqrt(max(0.0, 0.5 * (float(m.static_friction) + float(m.dynamic_friction))))


# PyBullet's limit on the shapes of one link (MAX_COMPOUND_COLLISION_SHAPES); more overflow its buffers.
_MAX_SHAPES = 16
_TOKEN_MASS = 1e-4  # kg

# Capsules and cylinders: cab's axis is local x, Bullet's local z. This rotation (about y by +90
# degrees, wxyz) takes Bullet's z axis onto x.
_Z_TO_X = (0.0, 0.0, 0.0, math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)


def _split_capsules(shapes: list) -> list:
    """Visual shapes with every capsule drawn as a cylinder and two spheres (TinyRenderer's own
    capsule mesh is coarse, with pointed ends); a textured capsule is drawn as its own mesh."""
    out = []
    for s in shapes:
        g = s.geometry
        if not isinstance(g, Capsule) or textured(s):
            out.append(s)
            continue
        pose = ss.pose_or_bad(s.pose)
        out.append(replace(s, geometry=Cylinder(g.radius, g.half_length)))
        for end in (-g.half_length, g.half_length):
            out.append(replace(s, geometry=Sphere(g.radius), pose=tuple(pose_mul(pose, (end, 0, 0, 1, 0, 0, 0)))))
    return out


@dataclass
class _MultiBody:
    """One Bullet multibody: a rigid body (no joints) or an articulation (URDF)."""
    uid: int
    kind: str  # static | dynamic | kinematic | articulation
    com_local: np.ndarray  # pose of the base's centre-of-mass frame in the base link frame
    joints: list[int] = field(default_factory=list)  # movable joints, URDF order
    links: dict[str, int] = field(default_factory=dict)  # link name -> link index (-1: base)
    com_inv: np.ndarray = field(init=False)  # pose of the base link frame in the com frame

    def __post_init__(self):
        self.com_inv = pose_inv(self.com_local)


@dataclass
class _Camera:
    spec: CameraSpec
    mount: int | None  # robot link index of a mounted camera, None for a fixed one
    local: np.ndarray  # cv pose: world pose (fixed) or pose in the mount link (mounted)
    projection: list[float]


class PybulletSimulator(ss.CameraAccessors, ss.LastStepContacts, Simulator):
    """PyBullet 3 (Bullet multibodies, TinyRenderer or EGL). Not thread-safe: one owner thread."""

    name = BACKEND

    def __init__(self, cfg: dict | None = None):
        cfg = ss.simulator_options(cfg, _KNOWN_OPTIONS, BACKEND)
        self._cfg = dict(cfg)  # for the render twin (render_samples)
        self._twin: PybulletSimulator | None = None
        self._render_enabled = bool(cfg.get("render", True))
        self._renderer = _renderer.choose(str(cfg.get("renderer", "auto"))) if self._render_enabled else None
        self._timestep_override = ss.timestep_option(cfg, BACKEND)
        physics = dict(cfg.get("physics") or {})
        bad = sorted(k for k in physics if k not in PHYSICS_DEFAULTS)
        if bad:
            raise ConfigError(f"unknown pybullet physics parameter(s) {bad}; known: {sorted(PHYSICS_DEFAULTS)}")
        self._physics = dict(PHYSICS_DEFAULTS)
        for k, v in physics.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise ConfigError(f"pybullet physics.{k} must be a positive number, got {v!r}")
            self._physics[k] = float(v)
        self._c: BulletClient | None = None
        self._closed = False

    # -- life cycle ---------------------------------------------------------------------------
    def build(self, scene: SceneSpec, embodiment: EmbodimentSpec) -> None:
        """Create the world: ground, bodies, articulated objects, the robot, cameras.

        - Ground: a static plane at ``scene.ground_z`` named ``"ground"``.
        - Bodies: one Bullet multibody each (of fixed-joint links when it has more shapes than a
          PyBullet link takes); primitives and OBJ meshes (convex hulls;
          non-convex triangle meshes only on static and kinematic bodies). Static and kinematic
          bodies have no mass (kinematic ones move only when code teleports them). Mass, centre of
          mass and inertia come from the density over the exact shapes (:mod:`.massprops`);
          ``mass`` rescales them. Friction: see :data:`PHYSICS_DEFAULTS`.
        - Articulated objects: PyBullet's URDF loader with the URDF's inertias and joint limits;
          ``joint_friction`` (a joint motor holding zero velocity with that force) and
          ``joint_damping`` override the URDF's ``<dynamics>`` when non-zero.
        - Robot: fixed base at ``base_pose``; position motors on every joint of ``joint_order()``;
          links of one arm never collide with each other or with the robot's body, the two arms
          collide with each other (as in the SAPIEN backend). Arms start at ``home_qpos`` with the
          grippers open; targets equal the start.
        - Cameras: scene cameras at their world pose, embodiment cameras on their ``mount_link``.
        """
        if self._c is not None or self._closed:
            raise SimulatorError("build() is called once per simulator")
        self._timestep = self._timestep_override or float(scene.timestep)
        self._scene_spec, self._emb = scene, embodiment
        ss.check_object_names(scene)
        with c_output_silenced():  # "argv[0]=" from the C side
            self._c = BulletClient(connection_mode=pybullet.DIRECT)
        try:
            self._egl_plugin = None
            if self._renderer is not None and self._renderer.kind == "egl":
                self._egl_plugin = _renderer.load_egl(self._c)
            self._build_world()
        except Exception:
            self.close()
            raise
        self._steps = 0
        self._contacts: list[Contact] | None = []

    def _build_world(self) -> None:
        """(Re)create everything in the client, in a fixed order (a rebuild gives the same ids)."""
        c, scene = self._c, self._scene_spec
        c.resetSimulation()
        c.setGravity(*[float(g) for g in scene.gravity])
        c.setPhysicsEngineParameter(fixedTimeStep=self._timestep, numSubSteps=0,
                                    numSolverIterations=int(self._physics["solver_iterations"]),
                                    deterministicOverlappingPairs=1)
        self._names: dict[tuple[int, int], str] = {}
        self._bodies: dict[str, _MultiBody] = {}
        self._ghosts: list[tuple[_MultiBody, int]] = []  # (body, collision-free body of extra visuals)
        self._texture_ids: dict[str, int] = {}  # image file -> texture id (resetSimulation drops them)
        self._blank_visual: int | None = None  # the invisible visual shape of links without one
        self._arts: dict[str, _MultiBody] = {}
        self._build_ground(scene)
        for body in scene.bodies:
            self._build_body(body)
        for obj in scene.articulations:
            self._build_articulated_object(obj, scene.default_material)
        self._object_order = scene.names()
        self._build_robot(self._emb, scene.default_material)
        self._build_cameras(list(scene.cameras) + list(self._emb.cameras))
        self._shading = _renderer.Shading.from_lighting(scene.lighting, self._physics["light_diffuse"],
                                                        self._physics["light_specular"])

    def _build_ground(self, scene: SceneSpec) -> None:
        c = self._c
        col = c.createCollisionShape(pybullet.GEOM_PLANE)
        vis = -1
        if self._render_enabled:
            vis = c.createVisualShape(pybullet.GEOM_BOX, halfExtents=[20.0, 20.0, 0.0005],
                                      visualFramePosition=[0.0, 0.0, -0.0005],
                                      rgbaColor=_renderer.display_color(scene.ground_color))
        uid = c.createMultiBody(0.0, col, vis, [0.0, 0.0, float(scene.ground_z)])
        self._set_material(uid, -1, scene.default_material)
        self._names[(uid, -1)] = "ground"

    def _set_material(self, uid: int, link: int, m: Material) -> None:
        self._c.changeDynamics(uid, link, lateralFriction=_bullet_friction(m),
                               rollingFriction=self._physics["rolling_friction_m"],
                               spinningFriction=self._physics["spinning_friction_m"],
                               restitution=math.sqrt(max(0.0, float(m.restitution))))

    # -- bodies -------------------------------------------------------------------------------
    def _shape_arrays(self, body, shapes: list, collision: bool) -> dict:
        """Arguments of createCollisionShapeArray / createVisualShapeArray for some of a body's shapes."""
        out: dict[str, list] = {"shapeTypes": [], "halfExtents": [], "radii": [], "lengths": [],
                                "fileNames": [], "meshScales": [], "flags": []}
        pos_key, orn_key = (("collisionFramePositions", "collisionFrameOrientations") if collision
                            else ("visualFramePositions", "visualFrameOrientations"))
        out[pos_key], out[orn_key] = [], []
        if not collision:
            out["rgbaColors"] = []
        for s in shapes:
            g = s.geometry
            pose = ss.pose_or_bad(s.pose)
            kind, half, radius, length, fname, scale, flags = pybullet.GEOM_BOX, [0.0] * 3, 0.0, 0.0, "", [1.0] * 3, 0
            if not collision and textured(s):  # a mesh with texture coordinates, in the shape frame
                kind, fname = pybullet.GEOM_MESH, uv_mesh(g)
            elif isinstance(g, Box):
                half = [float(h) for h in g.half_size]
            elif isinstance(g, Sphere):
                kind, radius = pybullet.GEOM_SPHERE, float(g.radius)
            elif isinstance(g, (Capsule, Cylinder)):
                kind = pybullet.GEOM_CAPSULE if isinstance(g, Capsule) else pybullet.GEOM_CYLINDER
                radius, length = float(g.radius), 2.0 * float(g.half_length)
                pose = tuple(pose_mul(pose, _Z_TO_X))
            elif isinstance(g, Mesh):
                if not os.path.isfile(g.path):
                    raise BadCommand(f"body {body.name!r}: mesh file not found: {g.path}")
                kind, fname, scale = pybullet.GEOM_MESH, g.path, [float(x) for x in g.scale]
                if collision and not g.convex:
                    if body.kind == "dynamic":
                        raise BadCommand(f"body {body.name!r}: a non-convex mesh collides only on static or "
                                         f"kinematic bodies; use convex=True or split the mesh")
                    flags = pybullet.GEOM_FORCE_CONCAVE_TRIMESH
            else:
                raise BadCommand(f"body {body.name!r}: unsupported geometry {type(g).__name__}")
            for key, value in (("shapeTypes", kind), ("halfExtents", half), ("radii", radius),
                               ("lengths", length), ("fileNames", fname), ("meshScales", scale),
                               ("flags", flags), (pos_key, list(pose[:3])), (orn_key, _xyzw(pose[3:]))):
                out[key].append(value)
            if not collision:
                # the renderer multiplies a texture by the colour: white shows the image as it is
                rgba = (1.0, 1.0, 1.0, *s.material.color[3:4]) if s.material.texture is not None else s.material.color
                out["rgbaColors"].append(_renderer.display_color(rgba))
        if not collision:
            del out["flags"]
        return out

    def _chunk_props(self, body, chunks: list[list]) -> list[massprops.MassProps | None]:
        """Mass properties of each chunk of collision shapes (None for an empty chunk), scaled so
        that the whole body has ``body.mass`` when it is given."""
        props = []
        for shapes in chunks:
            parts = []
            for sh in shapes:
                try:
                    parts.append(massprops.transformed(massprops.shape_props(sh.geometry, float(body.density)),
                                                       ss.pose_or_bad(sh.pose)))
                except ValueError as e:
                    raise BadCommand(f"body {body.name!r}: {e}") from None
            props.append(massprops.combine(parts) if parts else None)
        if body.mass is not None:
            if not body.mass > 0:
                raise BadCommand(f"body {body.name!r}: mass must be positive, got {body.mass}")
            k = float(body.mass) / sum(p.mass for p in props if p is not None)
            props = [None if p is None else massprops.MassProps(p.mass * k, p.com, p.inertia * k) for p in props]
        return props

    def _build_body(self, body) -> None:
        """A body is one Bullet multibody. PyBullet takes at most 16 shapes per link, so a body with
        more collision shapes is split into links of up to 16 shapes joined by fixed joints: one rigid
        body still, with each link's mass properties computed from its own shapes. The link structure
        comes from the collision shapes alone, so the physics is the same whether the world renders or
        not; visual shapes beyond 16 per link go to a collision-free ghost body that follows the body
        when a picture is taken, and a link left without visual shapes shows nothing (never its
        collision shapes: :meth:`_no_visual`)."""
        if body.kind not in ("static", "dynamic", "kinematic"):
            raise BadCommand(f"body {body.name!r}: unknown kind {body.kind!r}")
        c = self._c
        col_shapes = [sh for sh in body.shapes if sh.collision]
        vis_shapes = _split_capsules([sh for sh in body.shapes if sh.visual]) if self._render_enabled else []
        if body.kind == "dynamic" and not col_shapes:
            raise BadCommand(f"body {body.name!r}: a dynamic body needs a collision shape")
        n = max(1, -(-len(col_shapes) // _MAX_SHAPES))
        col_chunks = [col_shapes[i * _MAX_SHAPES:(i + 1) * _MAX_SHAPES] for i in range(n)]
        n_vis = max(n, -(-len(vis_shapes) // _MAX_SHAPES))
        vis_chunks = [vis_shapes[i * _MAX_SHAPES:(i + 1) * _MAX_SHAPES] for i in range(n_vis)]
        vis_chunks, ghost_chunks = vis_chunks[:n], vis_chunks[n:]
        for sh in body.shapes:  # checked on physics-only builds too
            if sh.visual and sh.material.texture is not None:
                texture_image(sh.material.texture, f"body {body.name!r}")
        cols, viss = [], []
        for chunk in col_chunks:
            cols.append(c.createCollisionShapeArray(**self._shape_arrays(body, chunk, True)) if chunk else -1)
            if chunk and cols[-1] < 0:
                raise SimulatorError(f"body {body.name!r}: a collision shape failed to build (bad mesh?)")
        for chunk in vis_chunks:
            viss.append(c.createVisualShapeArray(**self._shape_arrays(body, chunk, False)) if chunk
                        else self._no_visual())
        dynamic = body.kind == "dynamic"
        props = self._chunk_props(body, col_chunks) if dynamic else [None] * n
        masses, frames, moments = [], [], []
        for p in props:
            if p is None:  # a link of visual shapes only: a token mass keeps Bullet's inverse finite
                masses.append(_TOKEN_MASS if dynamic else 0.0)
                frames.append(np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
                moments.append(np.full(3, _TOKEN_MASS * 1e-4))
                continue
            m, axes = massprops.principal(p)
            masses.append(p.mass)
            frames.append(np.concatenate([p.com, mat_to_quat(axes)]))
            moments.append(m)
        pose = ss.pose_or_bad(body.pose)
        links = n - 1
        uid = c.createMultiBody(
            masses[0], cols[0], viss[0], list(pose[:3]), _xyzw(pose[3:]),
            baseInertialFramePosition=list(frames[0][:3]), baseInertialFrameOrientation=_xyzw(frames[0][3:]),
            linkMasses=masses[1:], linkCollisionShapeIndices=cols[1:], linkVisualShapeIndices=viss[1:],
            linkPositions=[[0.0, 0.0, 0.0]] * links, linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * links,
            linkInertialFramePositions=[list(f[:3]) for f in frames[1:]],
            linkInertialFrameOrientations=[_xyzw(f[3:]) for f in frames[1:]],
            linkParentIndices=[0] * links, linkJointTypes=[pybullet.JOINT_FIXED] * links,
            linkJointAxis=[[0.0, 0.0, 1.0]] * links)
        if uid < 0:
            raise SimulatorError(f"body {body.name!r}: PyBullet refused the body")
        first = col_shapes[0].material if col_shapes else self._scene_spec.default_material
        for link in range(-1, links):
            self._set_material(uid, link, first)
            self._names[(uid, link)] = body.name
            if dynamic:
                c.changeDynamics(uid, link, localInertiaDiagonal=[float(x) for x in moments[link + 1]])
        if dynamic:
            # damping belongs to the whole multibody; PyBullet 3.2.7 also writes a link call's
            # inertia onto the base when the same call sets damping, hence the separate calls
            c.changeDynamics(uid, -1, linearDamping=float(body.linear_damping),
                             angularDamping=float(body.angular_damping))
        mb = _MultiBody(uid, body.kind, frames[0])
        self._bodies[body.name] = mb
        for link, chunk in enumerate(vis_chunks, start=-1):
            self._apply_textures(body, uid, link, chunk)
        for chunk in ghost_chunks:
            vis = c.createVisualShapeArray(**self._shape_arrays(body, chunk, False))
            ghost = c.createMultiBody(0.0, -1, vis, list(pose[:3]), _xyzw(pose[3:]))
            if ghost < 0:
                raise SimulatorError(f"body {body.name!r}: PyBullet refused its extra visual shapes")
            self._apply_textures(body, ghost, -1, chunk)
            self._ghosts.append((mb, ghost))

    def _no_visual(self) -> int:
        """The visual shape index of a link that shows nothing. PyBullet's renderers (TinyRenderer and
        EGL alike) draw a link given no visual shape (index -1) as its collision shapes, in white: a
        body's links beyond its first (collision shapes past 16) had their collision boxes drawn over
        the body's own visual shapes, white, in the same places (white pot handles and wall bands,
        flickering with the depth order). Such a link gets instead a mesh of one degenerate
        triangle, which no rasteriser fills. Physics-only worlds render nothing: -1 there."""
        if not self._render_enabled:
            return -1
        if self._blank_visual is None:
            self._blank_visual = self._c.createVisualShape(pybullet.GEOM_MESH, vertices=[[0.0, 0.0, 0.0]] * 3,
                                                           indices=[0, 1, 2])
            if self._blank_visual < 0:
                raise SimulatorError("PyBullet refused the empty visual shape of a link without visual shapes")
        return self._blank_visual

    def _apply_textures(self, body, uid: int, link: int, shapes: list) -> None:
        """Put each textured shape's image on its visual shape (``shapes``: the link's visual shapes
        in creation order, which is PyBullet's shape index)."""
        for k, sh in enumerate(shapes):
            if textured(sh):
                self._c.changeVisualShape(uid, link, shapeIndex=k,
                                          textureUniqueId=self._texture_id(sh.material.texture, body.name))

    def _texture_id(self, path: str, body: str) -> int:
        """The client's texture of an image file, loaded once per (re)build of the world."""
        file = texture_image(path, f"body {body!r}")
        tid = self._texture_ids.get(file)
        if tid is None:
            try:
                tid = self._texture_ids[file] = self._c.loadTexture(file)
            except pybullet.error as e:
                raise SimulatorError(f"body {body!r}: PyBullet cannot load texture file {file}: {e}") from None
        return tid

    def _place_ghosts(self) -> None:
        """Put each ghost (a body's visual shapes beyond its links' capacity) on its body."""
        for mb, ghost in self._ghosts:
            p = self._link_pose(mb, -1)
            self._c.resetBasePositionAndOrientation(ghost, p[:3].tolist(), _xyzw(p[3:]))

    # -- articulations ------------------------------------------------------------------------
    def _load_urdf(self, urdf: str, fix_root: bool, pose, flags: int = 0) -> _MultiBody:
        if not os.path.isfile(urdf):
            raise BadCommand(f"URDF not found: {urdf}")
        c = self._c
        p = ss.pose_or_bad(pose)
        try:
            uid = c.loadURDF(urdf, list(p[:3]), _xyzw(p[3:]), useFixedBase=bool(fix_root),
                             flags=flags | pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_MAINTAIN_LINK_ORDER)
        except pybullet.error as e:
            raise BadCommand(f"cannot load URDF {urdf}: {e}") from e
        info = c.getDynamicsInfo(uid, -1)
        mb = _MultiBody(uid, "articulation", _pose_from_bullet(info[3], info[4]))
        mb.links[c.getBodyInfo(uid)[0].decode()] = -1
        for j in range(c.getNumJoints(uid)):
            ji = c.getJointInfo(uid, j)
            mb.links[ji[12].decode()] = j
            if ji[2] in (pybullet.JOINT_REVOLUTE, pybullet.JOINT_PRISMATIC):
                mb.joints.append(j)
        c.changeDynamics(uid, -1, linearDamping=0.0, angularDamping=0.0)  # the whole multibody
        if self._render_enabled:
            self._urdf_display_colors(uid)
        return mb

    def _urdf_display_colors(self, uid: int) -> None:
        """URDF colours are linear like every cab colour: give TinyRenderer their display values."""
        per_link: dict[int, int] = {}
        for v in self._c.getVisualShapeData(uid):
            link = v[1]
            k = per_link.get(link, 0)
            per_link[link] = k + 1
            self._c.changeVisualShape(uid, link, shapeIndex=k, rgbaColor=_renderer.display_color(v[7]))

    def _build_articulated_object(self, obj, default: Material) -> None:
        c = self._c
        mb = self._load_urdf(obj.urdf, obj.fix_root, obj.pose)
        for link in mb.links.values():
            self._set_material(mb.uid, link, default)
        for j in mb.joints:
            friction = float(obj.joint_friction) or float(c.getJointInfo(mb.uid, j)[7])
            c.setJointMotorControl2(mb.uid, j, pybullet.VELOCITY_CONTROL, targetVelocity=0.0, force=friction)
            if obj.joint_damping > 0:
                c.changeDynamics(mb.uid, j, jointDamping=float(obj.joint_damping))
        if obj.qpos is not None:
            q = ss.vector_or_bad(obj.qpos, len(mb.joints), f"initial qpos of {obj.name!r}")
            for j, v in zip(mb.joints, q.tolist()):
                c.resetJointState(mb.uid, j, v, 0.0)
        for link, index in mb.links.items():
            self._names[(mb.uid, index)] = f"{obj.name}/{link}"
        self._arts[obj.name] = mb

    def _build_robot(self, emb: EmbodimentSpec, default: Material) -> None:
        c = self._c
        mb = self._load_urdf(emb.urdf, True, emb.base_pose, pybullet.URDF_USE_SELF_COLLISION)
        self._robot = mb
        for link, index in mb.links.items():
            self._set_material(mb.uid, index, default)
            self._names[(mb.uid, index)] = f"{ROBOT}/{link}"
        self._filter_self_collisions(emb)
        by_name = {c.getJointInfo(mb.uid, j)[1].decode(): j for j in mb.joints}
        order = emb.joint_order()
        missing = [n for n in order if n not in by_name]
        if missing:
            raise BadCommand(f"embodiment {emb.name!r}: joints {missing} are not movable joints of {emb.urdf}")
        self._joint_names = list(order)
        self._drive_idx = [by_name[n] for n in order]
        gripper = {j for arm in emb.arms.values() for j in arm.gripper.joints}
        rate = self._physics["drive_rate_scale"] * self._timestep
        self._kp = [rate * (emb.gripper_stiffness / emb.gripper_damping if n in gripper
                            else emb.drive_stiffness / emb.drive_damping) for n in order]
        self._force = []
        for n, j in zip(order, self._drive_idx):
            effort = float(c.getJointInfo(mb.uid, j)[10])
            self._force.append(self._physics["gripper_force_n"] if n in gripper
                               else (effort if effort > 0 else self._physics["arm_force_nm"]))
        home = ss.start_joint_values(emb)
        start = np.array([home[n] for n in order])
        for j, v in zip(self._drive_idx, start.tolist()):
            c.resetJointState(mb.uid, j, v, 0.0)
        # movable joints outside joint_order (none in a well-formed embodiment) hold their start
        for j in mb.joints:
            if j not in self._drive_idx:
                name = c.getJointInfo(mb.uid, j)[1].decode()
                log.warning("robot joint %r is not in the embodiment's joint order; holding it", name)
                c.setJointMotorControl2(mb.uid, j, pybullet.POSITION_CONTROL,
                                        targetPosition=c.getJointState(mb.uid, j)[0],
                                        force=self._physics["arm_force_nm"])
        self._targets = np.zeros(len(order))
        self._vtargets = np.zeros(len(order))
        self._apply_targets(start)

    def _filter_self_collisions(self, emb: EmbodimentSpec) -> None:
        """Links of one arm never collide with each other nor with the robot's body; the two arms
        collide. Bullet pairs two colliders when each one's group meets the other's mask: every arm
        gets its own group bit, the body another, and each mask leaves out its own and the body's
        bit (arms) or every robot bit (body). Static objects stay out of the body's mask, as
        Bullet's default filter for a fixed base has it."""
        arm_bits = {name: 1 << (4 + i) for i, name in enumerate(sorted(emb.arms))}
        body_bit = 1 << (4 + len(arm_bits))
        robot_bits = body_bit
        for b in arm_bits.values():
            robot_bits |= b
        owner = {link: arm_bits[name] for name, arm in emb.arms.items() for link in arm.links}
        everything = -1
        static_group = 2  # Bullet's StaticFilter
        for link, index in self._robot.links.items():
            bit = owner.get(link)
            if bit is None:
                self._c.setCollisionFilterGroupMask(self._robot.uid, index, body_bit,
                                                    everything & ~robot_bits & ~static_group)
            else:
                self._c.setCollisionFilterGroupMask(self._robot.uid, index, bit, everything & ~(bit | body_bit))

    # -- cameras ------------------------------------------------------------------------------
    def _build_cameras(self, specs: list[CameraSpec]) -> None:
        self._cameras: dict[str, _Camera] = {}
        for spec in specs:
            ss.check_camera_spec(spec, self._cameras)
            mount = ss.camera_mount(spec, self._robot.links)
            K = intrinsics(int(spec.width), int(spec.height), float(spec.fovy_deg))
            proj = _renderer.projection_matrix(K, int(spec.width), int(spec.height), float(spec.near), float(spec.far))
            self._cameras[spec.name] = _Camera(spec, mount, np.asarray(ss.pose_or_bad(spec.pose)), proj)

    def close(self) -> None:
        """Disconnect the physics client (and the render twin's). Idempotent."""
        self._closed = True
        twin, self._twin = self._twin, None
        if twin is not None:
            twin.close()
        c, self._c = self._c, None
        if c is None:
            return
        try:
            c.disconnect()
        except pybullet.error:  # already gone
            log.debug("disconnect failed during close", exc_info=True)

    def _live(self) -> BulletClient:
        return ss.live_or_error(self._c, self._closed)

    @property
    def timestep(self) -> float:
        self._live()
        return self._timestep

    def step(self, n: int = 1) -> None:
        n = ss.step_count_or_bad(n)
        c = self._live()
        if n == 0:
            return
        for _ in range(n):
            c.stepSimulation()
        self._steps += n
        self._contacts = None

    # -- poses --------------------------------------------------------------------------------
    def _link_pose(self, mb: _MultiBody, index: int) -> np.ndarray:
        c = self._c
        if index == -1:
            pos, orn = c.getBasePositionAndOrientation(mb.uid)
            return pose_mul(_pose_from_bullet(pos, orn), mb.com_inv)
        s = c.getLinkState(mb.uid, index, computeForwardKinematics=1)
        return _pose_from_bullet(s[4], s[5])

    # -- robot --------------------------------------------------------------------------------
    @property
    def joint_names(self) -> list[str]:
        self._live()
        return list(self._joint_names)

    def _joint_states(self) -> list:
        return self._c.getJointStates(self._robot.uid, self._drive_idx)

    def get_qpos(self) -> np.ndarray:
        self._live()
        return np.array([s[0] for s in self._joint_states()], dtype=float)

    def get_qvel(self) -> np.ndarray:
        self._live()
        return np.array([s[1] for s in self._joint_states()], dtype=float)

    def set_qpos(self, qpos: np.ndarray) -> None:
        c = self._live()
        q = ss.vector_or_bad(qpos, len(self._joint_names), "robot qpos")
        for j, v in zip(self._drive_idx, q.tolist()):
            c.resetJointState(self._robot.uid, j, v, 0.0)
        self._apply_targets(q)

    def set_drive_targets(self, targets: np.ndarray, velocities: np.ndarray | None = None) -> None:
        self._live()
        t = ss.vector_or_bad(targets, len(self._joint_names), "drive targets")
        v = None if velocities is None else ss.vector_or_bad(velocities, len(self._joint_names), "drive velocity targets")
        self._apply_targets(t, v)

    def _apply_targets(self, t: np.ndarray, v: np.ndarray | None = None) -> None:
        v = np.zeros(len(t)) if v is None else v
        self._c.setJointMotorControlArray(self._robot.uid, self._drive_idx, pybullet.POSITION_CONTROL,
                                          targetPositions=t.tolist(), targetVelocities=v.tolist(),
                                          positionGains=self._kp, velocityGains=[1.0] * len(t),
                                          forces=self._force)
        self._targets = np.array(t, dtype=float)
        self._vtargets = np.array(v, dtype=float)

    def get_drive_targets(self) -> np.ndarray:
        self._live()
        return self._targets.copy()

    def get_link_pose(self, link: str) -> np.ndarray:
        self._live()
        return self._link_pose(self._robot, ss.robot_link_or_bad(self._robot.links, link))

    # -- objects ------------------------------------------------------------------------------
    def object_names(self) -> list[str]:
        self._live()
        return list(self._object_order)

    def _object(self, name: str) -> _MultiBody:
        self._live()
        mb = (self._bodies.get(name) or self._arts.get(name)) if isinstance(name, str) else None
        if mb is None:
            raise BadCommand(f"unknown object {name!r}")
        return mb

    def get_object_pose(self, name: str) -> np.ndarray:
        return self._link_pose(self._object(name), -1)

    def set_object_pose(self, name: str, pose) -> None:
        """Teleport a body (or an articulated object's root) and zero its velocity."""
        mb = self._object(name)
        p = pose_mul(ss.pose_or_bad(pose), mb.com_local)
        c = self._c
        c.resetBasePositionAndOrientation(mb.uid, p[:3].tolist(), _xyzw(p[3:]))
        c.resetBaseVelocity(mb.uid, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
        for j in mb.joints:
            c.resetJointState(mb.uid, j, c.getJointState(mb.uid, j)[0], 0.0)

    def get_object_velocity(self, name: str) -> np.ndarray:
        mb = self._object(name)
        if mb.kind in ("static", "kinematic"):
            return np.zeros(6)
        lin, ang = self._c.getBaseVelocity(mb.uid)
        return np.array(list(lin) + list(ang), dtype=float)

    def get_object_qpos(self, name: str) -> np.ndarray:
        mb = self._object(name)
        return np.array([s[0] for s in self._c.getJointStates(mb.uid, mb.joints)] if mb.joints else [], dtype=float)

    def set_object_qpos(self, name: str, qpos) -> None:
        """Set an articulated object's joints (and zero their velocities)."""
        mb = self._object(name)
        if mb.kind != "articulation":
            raise BadCommand(f"{name!r} is a rigid body; it has no joints")
        q = ss.vector_or_bad(qpos, len(mb.joints), f"qpos of {name!r}")
        for j, v in zip(mb.joints, q.tolist()):
            self._c.resetJointState(mb.uid, j, v, 0.0)

    def get_object_link_names(self, name: str) -> list[str]:
        self._live()
        mb = self._arts.get(name)
        return list(mb.links) if mb is not None else []

    def get_object_link_pose(self, name: str, link: str) -> np.ndarray:
        mb = self._object(name)
        return self._link_pose(mb, ss.object_link_or_bad(mb.links, name, link))

    # -- contacts -----------------------------------------------------------------------------
    def _compute_contacts(self) -> list[Contact]:
        """Impulse = sum over the pair's points of |normal + friction force| * timestep (N*s);
        point = mean position of the points that carried force."""
        names = self._names
        acc = ss.PairContacts()
        dt = self._timestep
        for pt in self._c.getContactPoints():
            f = math.sqrt(pt[9] * pt[9] + pt[10] * pt[10] + pt[12] * pt[12])
            if not f > 0.0:
                continue
            a, b = pt[5], pt[6]
            acc.add(names.get((pt[1], pt[3])), names.get((pt[2], pt[4])), f * dt,
                    0.5 * (a[0] + b[0]), 0.5 * (a[1] + b[1]), 0.5 * (a[2] + b[2]))
        return acc.contacts()

    # -- cameras ------------------------------------------------------------------------------
    def camera_pose(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if cam.mount is None:
            return cam.local.copy()
        return pose_mul(self._link_pose(self._robot, cam.mount), cam.local)

    def render(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if self._renderer is None:
            raise RendererUnavailable("this PyBullet simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        w, h = int(cam.spec.width), int(cam.spec.height)
        kind = pybullet.ER_BULLET_HARDWARE_OPENGL if self._renderer.kind == "egl" else pybullet.ER_TINY_RENDERER
        self._place_ghosts()
        out = self._c.getCameraImage(w, h, _renderer.view_matrix(self.camera_pose(name)), cam.projection,
                                     renderer=kind, flags=pybullet.ER_NO_SEGMENTATION_MASK,
                                     **self._shading.kwargs())
        rgba = np.asarray(out[2], dtype=np.uint8).reshape(h, w, 4)
        return np.ascontiguousarray(rgba[..., :3])

    def render_sample(self) -> tuple | None:
        """Base position and orientation (the centre-of-mass frame, as Bullet holds them) and
        joint positions of every multibody: the renderer draws from those."""
        c = self._live()
        if self._renderer is None:
            return None
        out = []
        for mb in self._multibodies():
            pos, orn = c.getBasePositionAndOrientation(mb.uid)
            q = tuple(s[0] for s in c.getJointStates(mb.uid, mb.joints)) if mb.joints else ()
            out.append((pos, orn, q))
        return tuple(out)

    def render_samples(self, name, samples, emit) -> None:
        """Pictured in a render twin: a second client built from the same description on first
        use (0.2-0.5 s for an aloha scene on a 2-core CPU), never stepped, into which each sample's
        poses are written. Writing poses into this world would disturb its contact caches, so it is
        not touched."""
        self._camera(name)
        if self._renderer is None:
            raise RendererUnavailable("this PyBullet simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        if self._twin is None:
            twin = PybulletSimulator(self._cfg)
            twin.build(self._scene_spec, self._emb)
            self._twin = twin
        twin = self._twin
        c = twin._c
        mbs = twin._multibodies()
        for sample in samples:
            if len(sample) != len(mbs):
                raise BadCommand("a render sample of another world")
            for mb, (pos, orn, q) in zip(mbs, sample):
                c.resetBasePositionAndOrientation(mb.uid, pos, orn)
                for j, v in zip(mb.joints, q):
                    c.resetJointState(mb.uid, j, v, 0.0)
            emit(twin.render(name))

    # -- state --------------------------------------------------------------------------------
    def _multibodies(self) -> list[_MultiBody]:
        return list(self._bodies.values()) + list(self._arts.values()) + [self._robot]

    def _layout(self) -> str:
        return json.dumps({"format": STATE_FORMAT, "bodies": [(n, b.kind) for n, b in self._bodies.items()],
                           "articulations": [(n, len(a.joints)) for n, a in self._arts.items()],
                           "robot": len(self._robot.joints), "joints": self._joint_names})

    def save_state(self) -> SimState:
        """Snapshot (``.npz``, no pickle) of base poses and velocities, joint positions and
        velocities (float64, as Bullet holds them), drive targets, step count and the last step's
        contacts. Written back at once (see the module docstring)."""
        c = self._live()
        mbs = self._multibodies()
        base = np.zeros((len(mbs), 13))
        q, qd = [], []
        for i, mb in enumerate(mbs):
            pos, orn = c.getBasePositionAndOrientation(mb.uid)
            lin, ang = c.getBaseVelocity(mb.uid)
            base[i] = list(pos) + list(orn) + list(lin) + list(ang)
            for s in (c.getJointStates(mb.uid, mb.joints) if mb.joints else []):
                q.append(s[0])
                qd.append(s[1])
        d = dict(base=base, qpos=np.array(q, float), qvel=np.array(qd, float), targets=self._targets.copy(),
                 vtargets=self._vtargets.copy(), steps=np.array(self._steps, np.int64))
        contacts = self.get_contacts()
        self._rebuild_with(d, contacts)
        return ss.pack_state(BACKEND, self._layout(), d, contacts)

    def restore_state(self, state: SimState) -> None:
        """Restore a snapshot of this world (or of another build of the same scene and robot)."""
        self._live()
        d, contacts = ss.unpack_state(state, BACKEND, self._layout())
        self._rebuild_with(d, contacts)

    def _rebuild_with(self, d: dict, contacts: list[Contact]) -> None:
        """Rebuild the world from its description (fresh contact caches), then write ``d``."""
        self._build_world()
        c = self._c
        k = 0
        for i, mb in enumerate(self._multibodies()):
            row = d["base"][i].tolist()
            c.resetBasePositionAndOrientation(mb.uid, row[:3], row[3:7])
            c.resetBaseVelocity(mb.uid, row[7:10], row[10:13])
            for j in mb.joints:
                c.resetJointState(mb.uid, j, float(d["qpos"][k]), float(d["qvel"][k]))
                k += 1
        self._apply_targets(np.asarray(d["targets"], float), np.asarray(d["vtargets"], float))
        self._steps = int(d["steps"])
        self._contacts = list(contacts)

    # -- provenance ---------------------------------------------------------------------------
    def versions(self) -> dict[str, str]:
        c = self._live()
        out = {"simulator": BACKEND, "pybullet": importlib.metadata.version("pybullet"),
               "bullet_api": str(c.getAPIVersion()), "timestep": repr(self._timestep),
               "solver_iterations": str(int(self._physics["solver_iterations"])),
               "render": "on" if self._renderer is not None else "off"}
        if self._renderer is not None:
            out["renderer"] = ("TinyRenderer (CPU)" if self._renderer.kind == "tiny"
                               else "EGL plugin (hardware OpenGL)")
            out["renderer_choice"] = self._renderer.reason
        return out

    # -- extras (not part of the contract) ----------------------------------------------------
    @property
    def steps(self) -> int:
        """Physics steps taken since build (restored with a snapshot)."""
        self._live()
        return self._steps
