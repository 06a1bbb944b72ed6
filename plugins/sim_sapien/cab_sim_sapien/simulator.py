"""The SAPIEN 3 backend of :class:`cab_core.contracts.simulator.Simulator`.

One ``sapien.Scene`` per attempt with a CPU PhysX system and, unless ``render: false``, a Vulkan
render system (on a CPU-only machine: Mesa lavapipe). Built once from a ``SceneSpec`` plus an
``EmbodimentSpec``; see :meth:`SapienSimulator.build` for what is created and how.

Options (the ``cfg`` dict of the plugin factory):

``render`` (bool, default true)
    Create the render system, visual shapes and cameras. With ``false`` the world is physics only:
    camera poses, intrinsics and sizes still work, :meth:`render` raises ``RendererUnavailable``.
``timestep`` (float, default: the scene's, 1/250 s)
    Overrides ``SceneSpec.timestep``.
``shader`` (str, default ``"default"``)
    SAPIEN camera shader directory (``default``, ``minimal``, ``rt``...).
``shadows`` (bool, default false)
    Shadow maps for the scene's lights, as RoboTwin renders them. Off by default: on lavapipe they
    cost two to three times the frame (two point lights mean twelve cube-map faces a picture;
    measured 640x480 ~35 -> ~90 ms, 320x240 ~8 -> ~55 ms). Turn on for visual parity on a GPU.
``shadow_map_size`` (int, default 2048)
    Shadow-map resolution when ``shadows`` is on.
``brdf_cache`` (bool, default true)
    Hand every camera SAPIEN's BRDF lookup table from the cache folder instead of letting SAPIEN
    generate it again in each process (5 s idle, up to 19 s under load on lavapipe); images are
    identical. ``false`` is SAPIEN's own behaviour. See :mod:`cab_sim_sapien.brdf`.
``pcm`` (bool, default false)
    PhysX's persistent contact manifolds (SAPIEN's default: on). Off: PhysX's SAT-based contact
    generation. With PCM, a box cut into a thin convex piece sometimes gets a contact whose
    normal leaves through the piece's far face: the inner finger pad pinching a bowl's rim in
    stack_bowls_three (a 2.6 cm flat pad inside the 5.35 cm concave wall, its edges in the
    neighbouring 4.5 mm wall wedges) got a 13-26 mm "penetration" straight up, which the solver
    removed in one step and threw the bowl off the table at 1.6 m/s and 39 rad/s; whether it
    appeared depended on float32 rounding, so three small bodies 30 cm away decided the verdict
    (issue 26). Without PCM no such contact was seen, and the 25 reference solutions succeed.
``max_depenetration_velocity`` (float, m/s, default: SAPIEN's, unbounded)
    The fastest PhysX pushes a dynamic body out of a penetration. 0.25 m/s made six reference
    solutions lose their grasps; 1 m/s still let a wrong contact spin a bowl at 5 rad/s.

Conventions: poses are numpy float64 ``[x, y, z, qw, qx, qy, qz]`` (SAPIEN's ``Pose.q`` is wxyz too);
SAPIEN stores everything in float32, so values read back are float32-exact. Cameras: cab's OpenCV
frame (x right, y down, z forward) is converted to SAPIEN's camera entity frame (x forward, y left,
z up) once, at build; ``camera_pose`` is computed from the mount link, not read from the renderer.

Snapshots (measured on the conformance world and on the aloha scenes, PhysX 5.3 CPU, 1 thread):

- ``restore_state`` reproduces everything the contract reads (poses, velocities, qpos, qvel, drive
  targets, link and camera poses) bit for bit, in this simulator or in another build of the same
  scene and robot; ``get_contacts`` returns the snapshot's last-step contacts until the next step.
- Stepping after a restore is bit-identical to stepping right after the ``save_state`` that made the
  snapshot (``save_state`` writes the state back into the world, see there), in the same or another
  build, whatever happened in between. Two restores of one snapshot replay identically.
- The write-back has a price: a run in which ``save_state`` is called differs from the same run
  without the call. Setting poses and joint positions rounds PhysX's hidden float32 state and drops
  its contact warm-start caches: max 1.4e-6 m over 1500 steps in the conformance world (objects at
  rest, arm moving freely), but amplified where the dynamics are sensitive (a stiff arm pressed into
  self-collision diverged by 0.1 rad). Take snapshots at the same points in runs that must match.
- Two builds of the same spec step identically (PhysX CPU is deterministic for the same scene built
  in the same order); renders of the same state are identical.

Textures (``Material.texture``): a textured box, sphere, cylinder or capsule is drawn as the
triangle mesh :func:`cab_core.contracts.texturing.uv_mesh` writes (texture coordinates in tiles of
0.3 m of surface: the image repeats every 0.3 m on every face, see there), with a
``RenderMaterial`` whose base-colour texture is the image (``RenderTexture2D``: sRGB, decoded to
linear like the plain colours, linear filtering, ``repeat`` addressing) and whose base colour is
white: SAPIEN multiplies the two, so the image replaces the plain colour (alpha, roughness and
metallic are the material's). Meshes keep their plain colour. Only the visual shape changes: the
collision shapes are the primitives as ever. The image is checked at every build, physics-only
ones included: a missing or unreadable file is a ``SimulatorError`` naming it.

Contacts are not collected per step: ``get_contacts`` reads PhysX's report of the last step when it
is first called after that step, so stepping costs nothing extra.
"""
from __future__ import annotations

import json
import logging
import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import sapien
from sapien.wrapper.urdf_loader import URDFLoader

from cab_core.contracts import simsupport as ss
from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.scene import Box, CameraSpec, Capsule, Cylinder, Material, Mesh, SceneSpec, Sphere, cache_dir
from cab_core.contracts.simulator import ROBOT, Contact, SimState, Simulator
from cab_core.contracts.texturing import texture_image, textured, uv_mesh
from cab_core.errors import BadCommand, ConfigError, RendererUnavailable, SimulatorError
from cab_core.geometry import mat_to_quat

from . import brdf as _brdf
from . import renderer as _renderer

log = logging.getLogger(__name__)

BACKEND = "sapien"
STATE_FORMAT = 1
_KNOWN_OPTIONS = {"render", "timestep", "shader", "shadows", "shadow_map_size", "brdf_cache", "name",
                  "max_depenetration_velocity", "pcm"}
MAX_DEPENETRATION_VELOCITY = None  # m/s; None: SAPIEN's own (unbounded), see the module's docstring
PCM = False  # PhysX's persistent contact manifolds, see the module's docstring

# Rotation taking SAPIEN camera axes (x forward, y left, z up) into OpenCV camera axes
# (x right, y down, z forward): the columns are SAPIEN's axes written in the OpenCV frame.
_CV_FROM_SAPIEN = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
_CV_TO_SAPIEN_POSE = sapien.Pose([0.0, 0.0, 0.0], mat_to_quat(_CV_FROM_SAPIEN).astype(np.float32))


def _sp(pose) -> sapien.Pose:
    """cab pose (7-vector, wxyz) -> sapien.Pose."""
    return sapien.Pose(np.asarray(pose[:3], dtype=np.float32), np.asarray(pose[3:7], dtype=np.float32))


def _np(pose: sapien.Pose) -> np.ndarray:
    """sapien.Pose -> float64 7-vector."""
    out = np.empty(7)
    out[:3] = pose.p
    out[3:] = pose.q
    return out


# The Vulkan context and its compiled pipelines live as long as some render object does. Without a
# reference held here, closing one attempt's scene destroys them and the next scene's first picture
# recompiles every pipeline (3-5 s on lavapipe). Held for the life of the process, created on the
# first render-enabled build.
_RENDERER_KEEPALIVE: list = []
_WARMED_SHADERS: set[str] = set()

# Pictures of SAPIEN's default shader pack that cab never reads and that no other picture is drawn
# from: composite outputs beside "Color" (linear depth, segmentation views, position), the
# G-buffer's "Custom" (object coordinates, which the lighting pass declares but does not read), and
# the line and point layers (cab draws no lines or points; their empty layers composite the same).
# In 8-bit RGBA instead of float RGBA they take 12 bytes a pixel less each: about 25 MiB for a
# 640x480 camera, 6 MiB for 320x240, in every worker; "Color" is the same bit for bit. The formats
# are process-wide settings that a camera reads when its first picture allocates them: set for that
# picture, then put back (SAPIEN's own for any other camera, such as another shader pack's).
_UNREAD_PICTURES = ("DepthLinear", "SegmentationView0", "SegmentationView1", "Position", "Custom", "Line",
                    "Point")
_SMALL, _FULL = "r8g8b8a8unorm", "r32g32b32a32sfloat"


def _shader_dir(shader: str) -> str:
    """A camera shader directory: a path, or the name of one shipped with SAPIEN."""
    shipped = os.path.join(os.path.dirname(sapien.__file__), "vulkan_shader", shader)
    path = shader if os.path.isdir(shader) else shipped
    if not any(os.path.isfile(os.path.join(path, f)) for f in ("gbuffer.vert", "camera.rgen")):
        raise ConfigError(f"sapien shader {shader!r}: {path} is not a SAPIEN camera shader directory")
    return path


class _PhysicsOnlyURDFLoader(URDFLoader):
    """SAPIEN's URDF loader minus ``<visual>`` elements: building their render materials needs a
    render device, which a physics-only simulator must not require."""

    def _parse_urdf(self, urdf_string):
        root = ET.fromstring(urdf_string.encode("utf-8"))
        for link in root.iter("link"):
            for visual in link.findall("visual"):
                link.remove(visual)
        return super()._parse_urdf(ET.tostring(root, encoding="unicode"))


@dataclass
class _Rigid:
    kind: str  # static | dynamic | kinematic
    entity: sapien.Entity
    component: object  # PhysxRigidDynamicComponent | PhysxRigidStaticComponent


@dataclass
class _Camera:
    spec: CameraSpec
    component: object | None  # RenderCameraComponent (None without rendering)
    link: object | None  # PhysxArticulationLinkComponent of a mounted camera
    local: sapien.Pose  # cv pose: world pose (fixed) or pose in the mount link (mounted)


class SapienSimulator(ss.CameraAccessors, ss.LastStepContacts, Simulator):
    """SAPIEN 3.0 (CPU PhysX, Vulkan renderer). Not thread-safe: one owner thread."""

    name = BACKEND

    def __init__(self, cfg: dict | None = None):
        cfg = ss.simulator_options(cfg, _KNOWN_OPTIONS, BACKEND)
        self._render_enabled = bool(cfg.get("render", True))
        self._timestep_override = ss.timestep_option(cfg, BACKEND)
        self._shader = str(cfg.get("shader", "default"))
        self._shader_path = _shader_dir(self._shader)
        self._shadows = bool(cfg.get("shadows", False))
        size = cfg.get("shadow_map_size", 2048)
        if isinstance(size, bool) or not isinstance(size, int) or size <= 0:
            raise ConfigError(f"sapien shadow_map_size must be a positive integer, got {size!r}")
        self._shadow_map_size = size
        self._brdf_cache = bool(cfg.get("brdf_cache", True))
        depen = cfg.get("max_depenetration_velocity", MAX_DEPENETRATION_VELOCITY)
        if depen is not None and (isinstance(depen, bool) or not isinstance(depen, (int, float))
                                  or not math.isfinite(depen) or depen <= 0):
            raise ConfigError(f"sapien max_depenetration_velocity must be a positive number of m/s or null, "
                              f"got {depen!r}")
        self._max_depenetration = None if depen is None else float(depen)
        pcm = cfg.get("pcm", PCM)
        if not isinstance(pcm, bool):
            raise ConfigError(f"sapien pcm must be true or false, got {pcm!r}")
        self._pcm = pcm
        self._lut = None
        self._scene = None
        self._closed = False

    # -- life cycle ---------------------------------------------------------------------------
    def build(self, scene: SceneSpec, embodiment: EmbodimentSpec) -> None:
        """Create the world: ground, lights, bodies, articulated objects, the robot, cameras.

        - Ground: a static plane at ``scene.ground_z`` named ``"ground"``.
        - Bodies: primitives and OBJ meshes (convex hulls; non-convex triangle meshes only for
          static and kinematic bodies). ``mass`` rescales the density-derived mass and inertia.
          Dynamic bodies leave a penetration at ``max_depenetration_velocity`` at most, when set.
        - Articulated objects: SAPIEN's URDF loader; a non-zero ``joint_friction`` /
          ``joint_damping`` overrides the URDF's ``<dynamics>`` (damping is a zero-stiffness drive).
        - Robot: fixed root at ``base_pose``, gravity off on its links (the drives then track
          targets without sag), position drives on every joint of ``joint_order()`` (arm joints with
          ``drive_*``, gripper joints with ``gripper_*``); any other active joint is held where it
          starts. Arms start at ``home_qpos`` with the grippers open; targets equal the start.
        - Cameras: scene cameras at their world pose, embodiment cameras on their ``mount_link``.
        """
        if self._scene is not None or self._closed:
            raise SimulatorError("build() is called once per simulator")
        self._timestep = self._timestep_override or float(scene.timestep)
        self._scene = self._create_scene(scene)
        try:
            self._build_world(scene, embodiment)
        except Exception:
            self.close()
            raise

    def _create_scene(self, scene: SceneSpec):
        # PhysxCpuSystem reads the process-wide scene config when it is created; set gravity for
        # this scene only, then put the previous config back.
        previous = sapien.physx.get_scene_config()
        cfg = sapien.physx.get_scene_config()
        cfg.gravity = np.asarray(scene.gravity, dtype=np.float32)
        cfg.enable_pcm = self._pcm
        sapien.physx.set_scene_config(cfg)
        try:
            physx = sapien.physx.PhysxCpuSystem()
        finally:
            sapien.physx.set_scene_config(previous)
        systems = [physx]
        self._rs = None
        if self._render_enabled:
            if not _RENDERER_KEEPALIVE:  # before the process's first Vulkan device
                _renderer.use_shader_cache(cache_dir() / "mesa")
            try:
                rs = sapien.render.RenderSystem()
            except RuntimeError as e:
                raise RendererUnavailable(_renderer.diagnose(e)) from e
            systems.append(rs)
            self._rs = rs
            if not _RENDERER_KEEPALIVE:
                _RENDERER_KEEPALIVE.append(sapien.render.SapienRenderer())
            if self._brdf_cache and _brdf.uses_lut(self._shader_path):
                self._lut = _brdf.texture(rs.device.name)
        s = sapien.Scene(systems)
        s.physx_system.timestep = self._timestep
        self._px = physx
        return s

    def _build_world(self, scene: SceneSpec, emb: EmbodimentSpec) -> None:
        s = self._scene
        self._materials: dict[tuple, object] = {}
        self._textures: dict[str, object] = {}
        self._names_by_ptr: dict[int, str] = {}
        self._bodies: dict[str, _Rigid] = {}
        self._arts: dict[str, object] = {}  # articulated objects
        self._art_links: dict[str, dict[str, object]] = {}
        self._object_order: list[str] = []
        self._steps = 0
        self._version = 0
        self._rendered_version = -1
        self._contacts: list[Contact] | None = []

        default = scene.default_material
        ground_mat = self._physx_material(default)
        ground = s.add_ground(float(scene.ground_z), render=self._rs is not None, material=ground_mat,
                              render_material=self._render_material(Material(color=scene.ground_color))
                              if self._rs is not None else None)
        self._register(ground.find_component_by_type(sapien.physx.PhysxRigidStaticComponent), "ground")

        if self._rs is not None:
            lt = scene.lighting
            s.ambient_light = list(lt.ambient)
            for direction, color in lt.directional:
                s.add_directional_light(list(direction), list(color), shadow=self._shadows,
                                        shadow_map_size=self._shadow_map_size)
            for position, color in lt.points:
                s.add_point_light(list(position), list(color), shadow=self._shadows,
                                  shadow_map_size=self._shadow_map_size)

        ss.check_object_names(scene)
        for body in scene.bodies:
            self._build_body(body)
        for obj in scene.articulations:
            self._build_articulated_object(obj, default)
        self._object_order = scene.names()
        self._build_robot(emb, default)
        self._build_cameras(list(scene.cameras) + list(emb.cameras))
        if self._rs is not None and self._shader not in _WARMED_SHADERS and self._cameras:
            # the first picture of a process compiles the shader pipelines (about 3 s on lavapipe):
            # pay it while building, not inside the first observation tool call
            self._warm_up()
            _WARMED_SHADERS.add(self._shader)

    # -- building helpers ---------------------------------------------------------------------
    def _register(self, component, name: str) -> None:
        self._names_by_ptr[component._physx_pointer] = name

    def _physx_material(self, m: Material):
        key = (float(m.static_friction), float(m.dynamic_friction), float(m.restitution))
        mat = self._materials.get(key)
        if mat is None:
            mat = self._materials[key] = sapien.physx.PhysxMaterial(*key)
        return mat

    @staticmethod
    def _render_material(m: Material):
        """A textured material's base colour is white (its alpha kept): SAPIEN multiplies the
        texture by the base colour, and the texture replaces the plain colour."""
        color = [float(c) for c in m.color]
        if m.texture is not None:
            color[:3] = [1.0, 1.0, 1.0]
        return sapien.render.RenderMaterial(base_color=color, roughness=float(m.roughness),
                                            metallic=float(m.metallic))

    def _texture(self, path: str, what: str):
        """The render texture of an image file, loaded once per simulator: sRGB (decoded to linear
        like the plain colours), linear filtering, repeated beyond 0..1."""
        file = texture_image(path, what)
        tex = self._textures.get(file)
        if tex is None:
            try:
                tex = self._textures[file] = sapien.render.RenderTexture2D(file, srgb=True)
            except Exception as e:  # noqa: BLE001 (SAPIEN raises plain RuntimeErrors)
                raise SimulatorError(f"{what}: cannot load texture file {file}: {e}") from e
        return tex

    def _build_body(self, body) -> None:
        if body.kind not in ("static", "dynamic", "kinematic"):
            raise BadCommand(f"body {body.name!r}: unknown kind {body.kind!r}")
        b = self._scene.create_actor_builder()
        b.set_physx_body_type(body.kind)
        n_collision = 0
        for shape in body.shapes:
            g = shape.geometry
            pose = _sp(ss.pose_or_bad(shape.pose))
            if isinstance(g, Mesh) and not os.path.isfile(g.path):
                raise BadCommand(f"body {body.name!r}: mesh file not found: {g.path}")
            if shape.visual and shape.material.texture is not None:  # checked on physics-only builds too
                texture_image(shape.material.texture, f"body {body.name!r}")
            if shape.collision:
                mat = self._physx_material(shape.material)
                dens = float(body.density)
                if isinstance(g, Box):
                    b.add_box_collision(pose, half_size=tuple(g.half_size), material=mat, density=dens)
                elif isinstance(g, Sphere):
                    b.add_sphere_collision(pose, radius=g.radius, material=mat, density=dens)
                elif isinstance(g, Capsule):
                    b.add_capsule_collision(pose, radius=g.radius, half_length=g.half_length, material=mat,
                                            density=dens)
                elif isinstance(g, Cylinder):
                    b.add_cylinder_collision(pose, radius=g.radius, half_length=g.half_length, material=mat,
                                             density=dens)
                elif isinstance(g, Mesh) and g.convex:
                    b.add_convex_collision_from_file(g.path, pose, scale=tuple(g.scale), material=mat,
                                                     density=dens)
                elif isinstance(g, Mesh):
                    if body.kind == "dynamic":
                        raise BadCommand(f"body {body.name!r}: a non-convex mesh collides only on static or "
                                         f"kinematic bodies; use convex=True or split the mesh")
                    b.add_nonconvex_collision_from_file(g.path, pose, scale=tuple(g.scale), material=mat)
                else:
                    raise BadCommand(f"body {body.name!r}: unsupported geometry {type(g).__name__}")
                n_collision += 1
            if shape.visual and self._rs is not None:
                rm = self._render_material(shape.material)
                if textured(shape):
                    rm.set_base_color_texture(self._texture(shape.material.texture, f"body {body.name!r}"))
                    b.add_visual_from_file(uv_mesh(g), pose, material=rm)
                elif isinstance(g, Box):
                    b.add_box_visual(pose, half_size=tuple(g.half_size), material=rm)
                elif isinstance(g, Sphere):
                    b.add_sphere_visual(pose, radius=g.radius, material=rm)
                elif isinstance(g, Capsule):
                    b.add_capsule_visual(pose, radius=g.radius, half_length=g.half_length, material=rm)
                elif isinstance(g, Cylinder):
                    b.add_cylinder_visual(pose, radius=g.radius, half_length=g.half_length, material=rm)
                elif isinstance(g, Mesh):
                    b.add_visual_from_file(g.path, pose, scale=tuple(g.scale), material=rm)
        b.set_initial_pose(_sp(ss.pose_or_bad(body.pose)))
        entity = b.build(name=body.name)
        cls = (sapien.physx.PhysxRigidStaticComponent if body.kind == "static"
               else sapien.physx.PhysxRigidDynamicComponent)
        comp = entity.find_component_by_type(cls)
        if len(comp.collision_shapes) != n_collision:  # the builder skips shapes that fail to cook
            raise SimulatorError(f"body {body.name!r}: {n_collision - len(comp.collision_shapes)} collision "
                                 f"shape(s) failed to build (bad mesh?)")
        if body.kind == "dynamic":
            if self._max_depenetration is not None:
                comp.max_depenetration_velocity = self._max_depenetration
            comp.linear_damping = float(body.linear_damping)
            comp.angular_damping = float(body.angular_damping)
            if body.mass is not None:
                if not body.mass > 0:
                    raise BadCommand(f"body {body.name!r}: mass must be positive, got {body.mass}")
                if comp.mass > 0:
                    comp.inertia = comp.inertia * (float(body.mass) / comp.mass)
                comp.mass = float(body.mass)
        self._bodies[body.name] = _Rigid(body.kind, entity, comp)
        self._register(comp, body.name)

    def _load_urdf(self, urdf: str, srdf: str | None, fix_root: bool, material: Material, pose):
        if not os.path.isfile(urdf):
            raise BadCommand(f"URDF not found: {urdf}")
        if self._rs is None:
            loader = _PhysicsOnlyURDFLoader()
            loader.set_scene(self._scene)
        else:
            loader = self._scene.create_urdf_loader()
        loader.fix_root_link = bool(fix_root)
        loader.set_material(float(material.static_friction), float(material.dynamic_friction),
                            float(material.restitution))
        try:
            builder = loader.load_file_as_articulation_builder(urdf, srdf if srdf and os.path.isfile(srdf) else None)
        except Exception as e:  # the URDF parser raises plain Exceptions
            raise BadCommand(f"cannot load URDF {urdf}: {e}") from e
        builder.set_initial_pose(_sp(ss.pose_or_bad(pose)))
        return builder.build()

    def _filter_self_collisions(self, emb: EmbodimentSpec) -> None:
        """Links of one arm never collide with each other (nor with the body the arms hang from):
        their primitive shapes overlap near the joints in ordinary poses, and the real arm's
        joint limits, not link contact, bound its motion. The two arms still collide with each
        other. PhysX ignores a pair whose third collision-group words share a bit."""
        arm_bits = {name: 1 << (20 + i) for i, name in enumerate(sorted(emb.arms))}
        owner = {}
        for name, arm in emb.arms.items():
            for link in arm.links:
                owner[link] = arm_bits[name]
        body_bits = 0
        for b in arm_bits.values():
            body_bits |= b
        for name, link in self._robot_links.items():
            bits = owner.get(name, body_bits)
            for shape in link.get_collision_shapes():
                g = list(shape.get_collision_groups())
                g[2] = int(g[2]) | bits
                shape.set_collision_groups(g)

    def _build_articulated_object(self, obj, default: Material) -> None:
        art = self._load_urdf(obj.urdf, None, obj.fix_root, default, obj.pose)
        art.name = obj.name
        joints = art.get_active_joints()
        for j in joints:
            if obj.joint_friction > 0:
                j.set_friction(float(obj.joint_friction))
            if obj.joint_damping > 0:
                j.set_drive_property(0.0, float(obj.joint_damping))
        if obj.qpos is not None:
            q = ss.vector_or_bad(obj.qpos, art.dof, f"initial qpos of {obj.name!r}")
            art.set_qpos(q.astype(np.float32))
        links = {}
        for link in art.get_links():
            links[link.name] = link
            self._register(link, f"{obj.name}/{link.name}")
        self._arts[obj.name] = art
        self._art_links[obj.name] = links

    def _build_robot(self, emb: EmbodimentSpec, default: Material) -> None:
        art = self._load_urdf(emb.urdf, emb.srdf, True, default, emb.base_pose)
        art.name = ROBOT
        self._robot = art
        self._robot_links = {}
        for link in art.get_links():
            link.disable_gravity = True
            self._robot_links[link.name] = link
            self._register(link, f"{ROBOT}/{link.name}")
        self._filter_self_collisions(emb)
        active = art.get_active_joints()
        index = {j.name: i for i, j in enumerate(active)}
        order = emb.joint_order()
        missing = [n for n in order if n not in index]
        if missing:
            raise BadCommand(f"embodiment {emb.name!r}: joints {missing} are not active joints of {emb.urdf}")
        self._joint_names = list(order)
        self._qidx = np.array([index[n] for n in order], dtype=np.int64)
        self._drives = [active[index[n]] for n in order]
        gripper = {j for arm in emb.arms.values() for j in arm.gripper.joints}
        for n, j in zip(order, self._drives):
            if n in gripper:
                j.set_drive_property(float(emb.gripper_stiffness), float(emb.gripper_damping))
            else:
                j.set_drive_property(float(emb.drive_stiffness), float(emb.drive_damping))
        q = art.get_qpos().astype(np.float64)
        start = q[self._qidx].copy()
        pos = {n: i for i, n in enumerate(order)}
        for n, v in ss.start_joint_values(emb).items():
            start[pos[n]] = v
        q[self._qidx] = start
        art.set_qpos(q.astype(np.float32))
        # active joints outside joint_order (none in a well-formed embodiment) hold their start
        for i, j in enumerate(active):
            if j.name not in pos:
                log.warning("robot joint %r is not in the embodiment's joint order; holding it at %.4f",
                            j.name, q[i])
                j.set_drive_property(float(emb.drive_stiffness), float(emb.drive_damping))
                j.set_drive_target(float(q[i]))
        self._targets = np.zeros(len(order))
        self._vtargets = np.zeros(len(order))
        self._apply_targets(start)

    def _warm_up(self) -> None:
        """Take the process's first picture with a throwaway 8x8 camera of this shader, removed
        afterwards: the pipelines are compiled as a real camera's first picture would compile them,
        and no camera of the world holds its pictures (about 190 bytes a pixel, 14 MiB for a 320x240
        camera) before it is pictured, such as the video's camera, pictured after the attempt."""
        world = self._cameras
        self._build_cameras([CameraSpec("cab_warm_up", 8, 8, 45.0)])
        warm, self._cameras = self._cameras["cab_warm_up"], world
        try:
            self._scene.update_render()
            self._picture(warm)
        finally:
            self._scene.remove_entity(warm.component.entity)

    def _build_cameras(self, specs: list[CameraSpec]) -> None:
        """The cameras; with SAPIEN's default shader pack, their unread pictures in 8 bits
        (``_UNREAD_PICTURES``: process-wide settings, read as a camera joins the scene, put back
        afterwards for any other camera)."""
        self._cameras: dict[str, _Camera] = {}
        slim = self._rs is not None and self._shader_path == _shader_dir("default")
        for name in _UNREAD_PICTURES if slim else ():
            sapien.render.set_picture_format(name, _SMALL)
        try:
            self._add_cameras(specs)
        finally:
            for name in _UNREAD_PICTURES if slim else ():
                sapien.render.set_picture_format(name, _FULL)

    def _add_cameras(self, specs: list[CameraSpec]) -> None:
        for spec in specs:
            ss.check_camera_spec(spec, self._cameras)
            local = _sp(ss.pose_or_bad(spec.pose))
            link = ss.camera_mount(spec, self._robot_links)
            comp = None
            if self._rs is not None:
                comp = sapien.render.RenderCameraComponent(int(spec.width), int(spec.height), self._shader_path)
                comp.set_fovy(math.radians(spec.fovy_deg), compute_x=True)
                comp.near, comp.far = float(spec.near), float(spec.far)
                comp.name = spec.name
                if link is None:
                    entity = sapien.Entity()
                    entity.name = spec.name
                    entity.add_component(comp)
                    entity.set_pose(local * _CV_TO_SAPIEN_POSE)
                    self._scene.add_entity(entity)
                else:
                    link.entity.add_component(comp)
                    comp.local_pose = local * _CV_TO_SAPIEN_POSE
                if self._lut is not None:  # possible once the camera is in the scene
                    comp.set_texture(_brdf.TEXTURE_NAME, self._lut)
            self._cameras[spec.name] = _Camera(spec, comp, link, local)

    def close(self) -> None:
        """Release the scene and every reference into it. Idempotent."""
        self._closed = True
        scene, self._scene = self._scene, None
        if scene is None:
            return
        for attr in ("_cameras", "_bodies", "_arts", "_art_links", "_robot", "_robot_links", "_drives",
                     "_names_by_ptr", "_materials", "_textures", "_contacts", "_px", "_rs"):
            if hasattr(self, attr):
                setattr(self, attr, None)
        try:
            scene.clear()
        except Exception:  # noqa: BLE001 (best effort at teardown)
            log.debug("scene.clear() failed during close", exc_info=True)
        del scene

    def _live(self):
        return ss.live_or_error(self._scene, self._closed)

    @property
    def timestep(self) -> float:
        self._live()
        return self._timestep

    def step(self, n: int = 1) -> None:
        n = ss.step_count_or_bad(n)
        self._live()
        if n == 0:
            return
        step = self._px.step
        for _ in range(n):
            step()
        self._steps += n
        self._contacts = None  # computed lazily from the last step's PhysX contacts
        self._version += 1

    # -- robot --------------------------------------------------------------------------------
    @property
    def joint_names(self) -> list[str]:
        self._live()
        return list(self._joint_names)

    def get_qpos(self) -> np.ndarray:
        self._live()
        return self._robot.get_qpos()[self._qidx].astype(np.float64)

    def get_qvel(self) -> np.ndarray:
        self._live()
        return self._robot.get_qvel()[self._qidx].astype(np.float64)

    def set_qpos(self, qpos: np.ndarray) -> None:
        self._live()
        q = ss.vector_or_bad(qpos, len(self._joint_names), "robot qpos")
        full = self._robot.get_qpos()
        full[self._qidx] = q
        self._robot.set_qpos(full)
        self._robot.set_qvel(np.zeros_like(full))
        self._apply_targets(q)
        self._touched()

    def set_drive_targets(self, targets: np.ndarray, velocities: np.ndarray | None = None) -> None:
        self._live()
        t = ss.vector_or_bad(targets, len(self._joint_names), "drive targets")
        v = None if velocities is None else ss.vector_or_bad(velocities, len(self._joint_names), "drive velocity targets")
        self._apply_targets(t, v)

    def _apply_targets(self, t: np.ndarray, v: np.ndarray | None = None) -> None:
        v = np.zeros(len(t)) if v is None else v
        for j, p, w in zip(self._drives, t.tolist(), v.tolist()):
            j.set_drive_target(p)
            j.set_drive_velocity_target(w)
        self._targets[:] = t
        self._vtargets[:] = v

    def get_drive_targets(self) -> np.ndarray:
        self._live()
        return self._targets.copy()

    def get_link_pose(self, link: str) -> np.ndarray:
        self._live()
        return _np(ss.robot_link_or_bad(self._robot_links, link).entity_pose)

    # -- objects ------------------------------------------------------------------------------
    def object_names(self) -> list[str]:
        self._live()
        return list(self._object_order)

    def _object(self, name: str):
        self._live()
        if isinstance(name, str):
            body = self._bodies.get(name)
            if body is not None:
                return body, None
            art = self._arts.get(name)
            if art is not None:
                return None, art
        raise BadCommand(f"unknown object {name!r}")

    def get_object_pose(self, name: str) -> np.ndarray:
        body, art = self._object(name)
        return _np(body.entity.pose) if body is not None else _np(art.get_root_pose())

    def set_object_pose(self, name: str, pose) -> None:
        """Teleport a body (or an articulated object's root) and zero its velocity."""
        body, art = self._object(name)
        p = _sp(ss.pose_or_bad(pose))
        if body is not None:
            body.entity.set_pose(p)
            if body.kind == "dynamic":
                body.component.set_linear_velocity([0.0, 0.0, 0.0])
                body.component.set_angular_velocity([0.0, 0.0, 0.0])
        else:
            art.set_root_pose(p)
            art.set_root_linear_velocity([0.0, 0.0, 0.0])
            art.set_root_angular_velocity([0.0, 0.0, 0.0])
            art.set_qvel(np.zeros(art.dof, dtype=np.float32))
        self._touched()

    def get_object_velocity(self, name: str) -> np.ndarray:
        body, art = self._object(name)
        if body is None:
            return np.concatenate([art.get_root_linear_velocity(), art.get_root_angular_velocity()]).astype(np.float64)
        if body.kind == "static":
            return np.zeros(6)
        c = body.component
        return np.concatenate([c.get_linear_velocity(), c.get_angular_velocity()]).astype(np.float64)

    def get_object_qpos(self, name: str) -> np.ndarray:
        body, art = self._object(name)
        return np.zeros(0) if art is None else art.get_qpos().astype(np.float64)

    def set_object_qpos(self, name: str, qpos) -> None:
        """Set an articulated object's joints (and zero their velocities)."""
        body, art = self._object(name)
        if art is None:
            raise BadCommand(f"{name!r} is a rigid body; it has no joints")
        q = ss.vector_or_bad(qpos, art.dof, f"qpos of {name!r}")
        art.set_qpos(q.astype(np.float32))
        art.set_qvel(np.zeros(art.dof, dtype=np.float32))
        self._touched()

    def get_object_link_names(self, name: str) -> list[str]:
        self._live()
        return list(self._art_links.get(name, {}))

    def get_object_link_pose(self, name: str, link: str) -> np.ndarray:
        self._object(name)
        return _np(ss.object_link_or_bad(self._art_links.get(name, {}), name, link).entity_pose)

    def _touched(self) -> None:
        """State changed without a step: images must be re-rendered; contacts keep the last step's."""
        self._version += 1

    # -- contacts -----------------------------------------------------------------------------
    def _compute_contacts(self) -> list[Contact]:
        """Impulse = sum of the point impulse magnitudes (N*s); point = mean position of the points
        that carried impulse."""
        # plain floats and math.sqrt: about 2.5x faster than numpy on PhysX's small per-point arrays
        names = self._names_by_ptr
        acc = ss.PairContacts()
        sqrt = math.sqrt
        for c in self._px.get_contacts():
            impulse, sx, sy, sz, k = 0.0, 0.0, 0.0, 0.0, 0
            for p in c.points:
                ix, iy, iz = p.impulse.tolist()
                m = sqrt(ix * ix + iy * iy + iz * iz)
                if m > 0.0:
                    x, y, z = p.position.tolist()
                    impulse += m
                    sx += x
                    sy += y
                    sz += z
                    k += 1
            if k == 0:
                continue
            b0, b1 = c.bodies
            acc.add(names.get(b0._physx_pointer), names.get(b1._physx_pointer), impulse, sx, sy, sz, k)
        return acc.contacts()

    # -- cameras ------------------------------------------------------------------------------
    def camera_pose(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if cam.link is None:
            return _np(cam.local)
        return _np(cam.link.entity_pose * cam.local)

    def render(self, name: str) -> np.ndarray:
        cam = self._camera(name)
        if cam.component is None:
            raise RendererUnavailable("this SAPIEN simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        if self._rendered_version != self._version:
            self._scene.update_render()
            self._rendered_version = self._version
        return self._picture(cam)

    @staticmethod
    def _picture(cam: _Camera) -> np.ndarray:
        cam.component.take_picture()
        rgba = cam.component.get_picture("Color")  # float32 RGBA in [0, 1]
        return (np.clip(rgba[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)

    def render_sample(self) -> bytes | None:
        """The pose of every entity of the scene (``Scene.pack_poses``, 28 bytes an entity, about
        3 us): what the renderer reads. A read of the entities' poses, which PhysX writes after
        each step; PhysX itself is not asked anything."""
        self._live()
        return None if self._rs is None else self._scene.pack_poses()

    def render_samples(self, name, samples, emit) -> None:
        """Each sample's poses go into the scene's entities only (``Scene.unpack_poses`` sets
        the entity poses the renderer reads without telling PhysX: bodies, joints, velocities and
        contact caches stay as they are), are pictured, and the current entity poses are put back."""
        cam = self._camera(name)
        if cam.component is None:
            raise RendererUnavailable("this SAPIEN simulator was built with render: false (physics only); "
                                      "build it with render: true to capture images")
        scene = self._scene
        now = scene.pack_poses()
        try:
            for sample in samples:
                if not isinstance(sample, bytes) or len(sample) != len(now):
                    raise BadCommand("a render sample of another world")
                scene.unpack_poses(sample)
                scene.update_render()
                emit(self._picture(cam))
        finally:
            scene.unpack_poses(now)
            self._rendered_version = -1  # the renderer holds the last sample's poses

    # -- state --------------------------------------------------------------------------------
    def _layout(self) -> str:
        arts = [(ROBOT, int(self._robot.dof))] + [(n, int(a.dof)) for n, a in self._arts.items()]
        bodies = [(n, b.kind) for n, b in self._bodies.items()]
        return json.dumps({"format": STATE_FORMAT, "bodies": bodies, "articulations": arts,
                           "joints": self._joint_names})

    def save_state(self) -> SimState:
        """Snapshot: body poses/velocities/sleep flags, articulation root poses/velocities and
        qpos/qvel (float32, exactly as PhysX holds them), drive targets, step count, and the last
        step's contacts. Encoded as an ``.npz`` archive (no pickle)."""
        self._live()
        bodies = list(self._bodies.values())
        pose = np.zeros((len(bodies), 7), np.float32)
        vel = np.zeros((len(bodies), 6), np.float32)
        asleep = np.zeros(len(bodies), np.bool_)
        for i, b in enumerate(bodies):
            p = b.entity.pose
            pose[i, :3], pose[i, 3:] = p.p, p.q
            if b.kind == "dynamic":
                c = b.component
                vel[i, :3], vel[i, 3:] = c.get_linear_velocity(), c.get_angular_velocity()
                asleep[i] = c.is_sleeping
        arts = [self._robot] + list(self._arts.values())
        root = np.zeros((len(arts), 13), np.float32)
        for i, a in enumerate(arts):
            p = a.get_root_pose()
            root[i, :3], root[i, 3:7] = p.p, p.q
            root[i, 7:10], root[i, 10:] = a.get_root_linear_velocity(), a.get_root_angular_velocity()
        qpos = np.concatenate([a.get_qpos() for a in arts]).astype(np.float32)
        qvel = np.concatenate([a.get_qvel() for a in arts]).astype(np.float32)
        d = dict(body_pose=pose, body_vel=vel, body_asleep=asleep, root=root, qpos=qpos, qvel=qvel,
                 targets=self._targets.copy(), vtargets=self._vtargets.copy(),
                 steps=np.array(self._steps, np.int64))
        contacts = self.get_contacts()
        # Re-apply the snapshot to this world at once. PhysX keeps float32 internals that the API
        # does not expose (centre-of-mass frames, link spatial velocities); writing the state back
        # puts them in exactly the form a later restore produces, so "save, do anything, restore,
        # step" replays "save, step" bit for bit. The price: a snapshot perturbs the run it is taken
        # from by float32 rounding (about 1e-9 to 1e-6 m), identically on every run that takes it.
        self._apply_state(d, contacts)
        return ss.pack_state(BACKEND, self._layout(), d, contacts)

    def restore_state(self, state: SimState) -> None:
        """Restore a snapshot of this world (or of another build of the same scene and robot)."""
        self._live()
        d, contacts = ss.unpack_state(state, BACKEND, self._layout())
        self._apply_state(d, contacts)

    def _apply_state(self, d: dict, contacts: list[Contact]) -> None:
        for i, b in enumerate(self._bodies.values()):
            row = d["body_pose"][i]
            b.entity.set_pose(sapien.Pose(row[:3], row[3:]))
            if b.kind == "dynamic":
                c = b.component
                c.set_linear_velocity(d["body_vel"][i, :3])
                c.set_angular_velocity(d["body_vel"][i, 3:])
                if d["body_asleep"][i]:
                    c.put_to_sleep()
        arts = [self._robot] + list(self._arts.values())
        k = 0
        for i, a in enumerate(arts):
            r = d["root"][i]
            a.set_root_pose(sapien.Pose(r[:3], r[3:7]))
            n = a.dof
            a.set_qpos(d["qpos"][k:k + n])
            a.set_qvel(d["qvel"][k:k + n])
            a.set_root_linear_velocity(r[7:10])
            a.set_root_angular_velocity(r[10:])
            k += n
        self._apply_targets(np.asarray(d["targets"], np.float64),
                            np.asarray(d["vtargets"], np.float64) if "vtargets" in d else None)
        self._steps = int(d["steps"])
        self._contacts = list(contacts)
        self._touched()

    # -- provenance ---------------------------------------------------------------------------
    def versions(self) -> dict[str, str]:
        self._live()
        out = {"simulator": BACKEND, "sapien": str(sapien.__version__), "physx": str(sapien.physx.version()),
               "timestep": repr(self._timestep), "render": "on" if self._rs is not None else "off",
               "pcm": "on" if self._pcm else "off",
               "max_depenetration_velocity": "unbounded" if self._max_depenetration is None
               else repr(self._max_depenetration)}
        if self._rs is not None:
            out["shader"] = self._shader
            out["shadows"] = f"on ({self._shadow_map_size})" if self._shadows else "off"
            out["brdf_lut"] = _brdf.source() if self._lut is not None else "sapien"
            try:
                device = self._rs.device.name
            except Exception:  # noqa: BLE001
                device = None
            out.update(_renderer.describe_device(device))
        return out

    # -- extras (not part of the contract) ----------------------------------------------------
    @property
    def steps(self) -> int:
        """Physics steps taken since build (restored with a snapshot)."""
        self._live()
        return self._steps
