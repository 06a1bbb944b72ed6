"""Write one MJCF model from a :class:`SceneSpec` plus an :class:`EmbodimentSpec`.

Nothing here is task specific: every body, articulated object, camera and light of the scene, and
the robot from its URDF, go through the same conversion. The MJCF uses MuJoCo's own elements only
(no URDF import), so names, frames, collision filters and drives are under this module's control:

- Bodies are named as the contract reports them: ``<body>``, ``<object>/<link>``, ``robot/<link>``;
  the ground plane belongs to the world body. Dynamic bodies get a free joint; static and kinematic
  bodies are mocap bodies (welded to the world for the physics, moved only by code).
- Collision geoms sit in geom group 3 (never drawn), visual geoms in group 1 (drawn, massless, no
  contacts), so inertia comes from collision geoms only (``inertiagrouprange``).
- Capsules and cylinders lie along local x in cab and along z in MuJoCo: a quarter turn about y.
- Textures (``Material.texture``): a textured box, sphere, cylinder or capsule's visual geom is a
  mesh geom of the OBJ :func:`cab_core.contracts.texturing.uv_mesh` writes, with its texture
  coordinates (tiles of 0.3 m of surface: the image repeats every 0.3 m on every face, see there),
  and a material of a ``2d`` texture from the image file. MuJoCo's own mapping of a 2d texture onto
  a primitive (projected along the geom's z axis, ``texrepeat``/``texuniform``) would streak it
  down a box's sides, hence the mesh. MuJoCo multiplies the texture by the material colour, which
  is white (alpha kept): the image replaces the plain colour, its bytes shown as they are (as the
  sRGB-encoded plain colours are). Meshes keep their plain colour. The geom stays visual only
  (group 1, no contacts, no mass): the collision geoms are the primitives as ever. A missing or
  unreadable image is a ``SimulatorError`` naming it, physics-only builds included.
- Cameras: cab's OpenCV frame (x right, y down, z forward) is MuJoCo's camera frame (x right, y up,
  looking along -z) turned half a turn about x.
- The robot: gravity compensated links (``gravcomp``), one position servo per driven joint with the
  embodiment's stiffness and damping, and no contacts between links of one arm or between an arm
  and the body it hangs from (as the SAPIEN backend filters them).
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from cab_core.contracts import scene as sc
from cab_core.contracts.embodiment import EmbodimentSpec
from cab_core.contracts.simsupport import camera_mount, check_camera_spec, check_object_names, pose_or_bad
from cab_core.contracts.simulator import ROBOT
from cab_core.contracts.texturing import texture_image, textured, uv_mesh
from cab_core.errors import BadCommand
from cab_core.geometry import axis_angle_quat, euler_quat, quat_mul, quat_to_mat

from .physics import PhysicsParams

VISUAL_GROUP = 1
COLLISION_GROUP = 3
_X_FROM_Z = axis_angle_quat([0.0, 1.0, 0.0], math.pi / 2)  # MuJoCo's z axis onto cab's x axis
_MJ_CAM_FROM_CV = np.array([0.0, 1.0, 0.0, 0.0])  # half a turn about x


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def srgb(rgba) -> tuple[float, ...]:
    """cab colours are linear; MuJoCo's renderer writes its colours to the image as they are, so
    they are encoded to sRGB here (as SAPIEN's renderer does at its output)."""
    c = np.clip(np.asarray(rgba[:3], float), 0.0, 1.0)
    enc = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return tuple(float(v) for v in enc) + tuple(float(a) for a in rgba[3:4])


def _pose_or_bad(pose, what: str) -> tuple[float, ...]:
    try:
        return pose_or_bad(pose)
    except BadCommand as e:
        raise BadCommand(f"{what}: {e}") from None


@dataclass
class Camera:
    spec: sc.CameraSpec
    body: str | None  # MJCF body of a mounted camera (None: fixed in the world)
    local: tuple[float, ...]  # OpenCV-frame pose: world pose, or pose in the mount body


@dataclass
class Articulation:
    name: str
    root: str  # MJCF body name of the root link
    links: dict[str, str]  # URDF link -> MJCF body name
    joints: list[str]  # MJCF names of the active joints, URDF order
    fixed: bool  # root welded to the world (a mocap body)


@dataclass
class Plan:
    """The written model and what the simulator needs to find its parts."""
    xml: str
    bodies: dict[str, str] = field(default_factory=dict)  # scene body -> kind
    articulations: dict[str, Articulation] = field(default_factory=dict)
    robot: Articulation | None = None
    actuators: list[str] = field(default_factory=list)  # joint_order(), one servo each
    cameras: dict[str, Camera] = field(default_factory=dict)
    masses: dict[str, float] = field(default_factory=dict)  # scene body -> mass to impose after compile
    damping: dict[str, tuple[float, float]] = field(default_factory=dict)  # body -> (linear, angular) 1/s


# -- URDF -------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _ZCylinder(sc.Cylinder):
    """A URDF cylinder: its axis is already MuJoCo's z, so it is written without the quarter turn."""


@dataclass
class _UrdfJoint:
    name: str
    kind: str
    parent: str
    child: str
    pose: tuple[float, ...]
    axis: tuple[float, float, float]
    limit: tuple[float, float] | None
    damping: float
    friction: float


def _origin(el) -> tuple[float, ...]:
    o = el.find("origin") if el is not None else None
    xyz = [float(v) for v in (o.get("xyz", "0 0 0").split() if o is not None else (0, 0, 0))]
    rpy = [float(v) for v in (o.get("rpy", "0 0 0").split() if o is not None else (0, 0, 0))]
    return tuple(xyz) + tuple(euler_quat(*rpy))


def _parse_urdf(path: str):
    """(links {name: element}, joints [_UrdfJoint], root link, named colours); BadCommand for a
    missing or malformed file."""
    if not os.path.isfile(path):
        raise BadCommand(f"URDF not found: {path}")
    try:
        return _read_urdf(ET.parse(path).getroot(), path)
    except (ET.ParseError, ValueError, AttributeError, TypeError) as e:
        raise BadCommand(f"cannot read URDF {path}: {type(e).__name__}: {e}") from None


def _read_urdf(root, path: str):
    colours = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None and m.get("name"):
            colours[m.get("name")] = tuple(float(v) for v in c.get("rgba").split())
    links = {link.get("name"): link for link in root.findall("link")}
    joints = []
    for j in root.findall("joint"):
        lim = j.find("limit")
        dyn = j.find("dynamics")
        kind = j.get("type")
        limit = None
        if lim is not None and kind in ("revolute", "prismatic"):
            limit = (float(lim.get("lower", 0)), float(lim.get("upper", 0)))
        axis = j.find("axis")
        joints.append(_UrdfJoint(
            name=j.get("name"), kind=kind, parent=j.find("parent").get("link"), child=j.find("child").get("link"),
            pose=_origin(j), axis=tuple(float(v) for v in (axis.get("xyz").split() if axis is not None else (1, 0, 0))),
            limit=limit, damping=float(dyn.get("damping", 0)) if dyn is not None else 0.0,
            friction=float(dyn.get("friction", 0)) if dyn is not None else 0.0))
    children = {j.child for j in joints}
    roots = [n for n in links if n not in children]
    if len(roots) != 1:
        raise BadCommand(f"URDF {path}: expected one root link, found {roots}")
    for j in joints:
        if j.kind not in ("revolute", "continuous", "prismatic", "fixed"):
            raise BadCommand(f"URDF {path}: joint {j.name!r} of type {j.kind!r} is not supported")
    return links, joints, roots[0], colours


# -- the writer -------------------------------------------------------------------------------------


class MjcfWriter:
    """Builds the MJCF tree; :meth:`write` returns the :class:`Plan`."""

    def __init__(self, physics: PhysicsParams):
        self.phys = physics
        self.root = ET.Element("mujoco", model="cab")
        self._assets = ET.SubElement(self.root, "asset")
        self._meshes: dict[tuple, str] = {}
        self._materials: dict[tuple, str] = {}  # (image file, alpha) -> textured material
        self._excludes: list[tuple[str, str]] = []
        self.plan = Plan(xml="")

    # geometry ------------------------------------------------------------------------------------
    def _mesh_asset(self, g: sc.Mesh, what: str) -> str:
        if not os.path.isfile(g.path):
            raise BadCommand(f"{what}: mesh file not found: {g.path}")
        key = (os.path.abspath(g.path), tuple(float(s) for s in g.scale))
        name = self._meshes.get(key)
        if name is None:
            name = self._meshes[key] = f"mesh{len(self._meshes)}"
            ET.SubElement(self._assets, "mesh", name=name, file=key[0], scale=_fmt(key[1]))
        return name

    def _geom(self, parent, g, pose, what: str) -> ET.Element:
        """A geom of cab geometry ``g`` at ``pose`` (body frame), without role attributes."""
        quat = np.asarray(pose[3:7], float)
        attrs: dict[str, str] = {}
        if isinstance(g, sc.Box):
            attrs.update(type="box", size=_fmt(g.half_size))
        elif isinstance(g, sc.Sphere):
            attrs.update(type="sphere", size=_fmt([g.radius]))
        elif isinstance(g, _ZCylinder):
            attrs.update(type="cylinder", size=_fmt([g.radius, g.half_length]))
        elif isinstance(g, (sc.Capsule, sc.Cylinder)):
            attrs.update(type="capsule" if isinstance(g, sc.Capsule) else "cylinder",
                         size=_fmt([g.radius, g.half_length]))
            quat = quat_mul(quat, _X_FROM_Z)
        elif isinstance(g, sc.Mesh):
            attrs.update(type="mesh", mesh=self._mesh_asset(g, what))
        else:
            raise BadCommand(f"{what}: unsupported geometry {type(g).__name__}")
        return ET.SubElement(parent, "geom", pos=_fmt(pose[:3]), quat=_fmt(quat), **attrs)

    def _collision(self, el: ET.Element, m: sc.Material, density: float | None = None) -> None:
        p = self.phys
        el.set("group", str(COLLISION_GROUP))
        el.set("friction", _fmt([m.dynamic_friction, p.torsional_friction, p.rolling_friction]))
        el.set("condim", str(p.condim))
        el.set("solref", _fmt(p.contact_solref))
        el.set("solimp", _fmt(p.contact_solimp))
        el.set("margin", repr(float(p.contact_margin)))
        el.set("gap", repr(float(p.contact_margin)))
        el.set("rgba", "0 0 0 0")
        if density is not None:
            el.set("density", repr(float(density)))

    @staticmethod
    def _visual(el: ET.Element, rgba) -> None:
        el.set("group", str(VISUAL_GROUP))
        el.set("contype", "0")
        el.set("conaffinity", "0")
        el.set("density", "0")
        el.set("rgba", _fmt(srgb(rgba)))

    def _shapes(self, parent, shapes: list[sc.Shape], density: float | None, what: str) -> None:
        for shape in shapes:
            pose = _pose_or_bad(shape.pose, f"{what}: shape pose")
            g = shape.geometry
            if shape.collision:
                if isinstance(g, sc.Mesh) and not g.convex:
                    raise BadCommand(f"{what}: MuJoCo collides a mesh as its convex hull; a non-convex "
                                     f"collision mesh must be split into convex pieces (convex=True)")
                self._collision(self._geom(parent, g, pose, what), shape.material, density)
            if not shape.visual:
                continue
            # the image is checked on meshes too, which keep their colour
            image = None if shape.material.texture is None else texture_image(shape.material.texture, what)
            if textured(shape):
                el = self._geom(parent, sc.Mesh(uv_mesh(g)), pose, what)
                self._visual(el, shape.material.color)
                del el.attrib["rgba"]  # a geom's own rgba would override its material's colour
                el.set("material", self._textured_material(image, float(shape.material.color[3])))
            else:
                self._visual(self._geom(parent, g, pose, what), shape.material.color)

    def _textured_material(self, image: str, alpha: float) -> str:
        """A material showing ``image`` through the mesh's texture coordinates (repeated beyond
        0..1). MuJoCo multiplies the texture by the material colour: white shows the image as it is.
        Specular and shininess are MuJoCo's defaults, as on the plain-coloured geoms."""
        key = (image, alpha)
        name = self._materials.get(key)
        if name is None:
            name = self._materials[key] = f"texmat{len(self._materials)}"
            tex = f"tex{len(self._materials) - 1}"
            ET.SubElement(self._assets, "texture", name=tex, type="2d", file=image)
            ET.SubElement(self._assets, "material", name=name, texture=tex, rgba=_fmt((1.0, 1.0, 1.0, alpha)))
        return name

    # world ---------------------------------------------------------------------------------------
    def _options(self, scene: sc.SceneSpec, timestep: float, cameras: list[sc.CameraSpec]) -> None:
        p = self.phys
        ET.SubElement(self.root, "compiler", angle="radian", inertiafromgeom="auto",
                      inertiagrouprange=f"{COLLISION_GROUP} {COLLISION_GROUP}", balanceinertia="true",
                      boundmass="1e-6", boundinertia="1e-10", autolimits="true")
        opt = ET.SubElement(self.root, "option", timestep=repr(float(timestep)), gravity=_fmt(scene.gravity),
                            integrator=p.integrator, cone=p.cone, impratio=repr(float(p.impratio)),
                            iterations=str(p.solver_iterations), tolerance=repr(float(p.solver_tolerance)),
                            noslip_iterations=str(p.noslip_iterations))
        ET.SubElement(opt, "flag", warmstart="enable")
        vis = ET.SubElement(self.root, "visual")
        w = max([c.width for c in cameras] + [64])
        h = max([c.height for c in cameras] + [64])
        ET.SubElement(vis, "global", offwidth=str(w), offheight=str(h))
        lt = scene.lighting
        ET.SubElement(vis, "headlight", ambient=_fmt(lt.ambient), diffuse="0 0 0", specular="0 0 0")
        near = min([c.near for c in cameras] + [0.1])
        far = max([c.far for c in cameras] + [10.0])
        ET.SubElement(vis, "map", znear=repr(float(near)), zfar=repr(float(far)))
        ET.SubElement(vis, "quality", shadowsize="0")
        # znear/zfar are fractions of the extent: extent 1 makes them metres
        ET.SubElement(self.root, "statistic", extent="1", center="0 0 0.8")

    def _lights(self, world, scene: sc.SceneSpec) -> None:
        for direction, colour in scene.lighting.directional:
            ET.SubElement(world, "light", directional="true", dir=_fmt(direction), pos="0 0 3",
                          diffuse=_fmt(colour), specular="0.1 0.1 0.1", castshadow="false")
        for position, colour in scene.lighting.points:
            ET.SubElement(world, "light", pos=_fmt(position), dir="0 0 -1", diffuse=_fmt(colour),
                          specular="0.1 0.1 0.1", castshadow="false")

    def _body(self, world, body: sc.Body) -> None:
        what = f"body {body.name!r}"
        if body.kind not in ("static", "dynamic", "kinematic"):
            raise BadCommand(f"{what}: unknown kind {body.kind!r}")
        pose = _pose_or_bad(body.pose, f"{what}: pose")
        el = ET.SubElement(world, "body", name=body.name, pos=_fmt(pose[:3]), quat=_fmt(pose[3:]))
        if body.kind == "dynamic":
            ET.SubElement(el, "freejoint", name=body.name)
            if body.mass is not None:
                if not body.mass > 0:
                    raise BadCommand(f"{what}: mass must be positive, got {body.mass}")
                self.plan.masses[body.name] = float(body.mass)
            self.plan.damping[body.name] = (float(body.linear_damping), float(body.angular_damping))
            if not any(s.collision for s in body.shapes):
                raise BadCommand(f"{what}: a dynamic body needs a collision shape (its mass comes from them)")
        else:
            el.set("mocap", "true")
        self._shapes(el, body.shapes, float(body.density), what)
        self.plan.bodies[body.name] = body.kind

    # URDF objects ----------------------------------------------------------------------------------
    def _urdf(self, parent, prefix: str, path: str, pose, root_mode: str, material: sc.Material,
              joint_damping: float | None = None, joint_friction: float | None = None,
              gravcomp: bool = False) -> Articulation:
        links, joints, root, colours = _parse_urdf(path)
        by_parent: dict[str, list[_UrdfJoint]] = {}
        for j in joints:
            by_parent.setdefault(j.parent, []).append(j)
        art = Articulation(name=prefix, root=f"{prefix}/{root}", links={}, joints=[], fixed=root_mode != "free")

        def add_link(parent_el, link: str, frame, joint: _UrdfJoint | None):
            name = f"{prefix}/{link}"
            el = ET.SubElement(parent_el, "body", name=name, pos=_fmt(frame[:3]), quat=_fmt(frame[3:]))
            if gravcomp:
                el.set("gravcomp", "1")
            art.links[link] = name
            self._link_contents(el, links[link], colours, material, f"link {name!r}", os.path.dirname(path))
            if joint is not None and joint.kind != "fixed":
                jn = f"{prefix}/{joint.name}"
                attrs = dict(name=jn, type="slide" if joint.kind == "prismatic" else "hinge", pos="0 0 0",
                             axis=_fmt(joint.axis))
                if joint.limit is not None:
                    attrs.update(limited="true", range=_fmt(joint.limit))
                damping = joint.damping if joint_damping is None else joint_damping
                friction = joint.friction if joint_friction is None else joint_friction
                armature = self.phys.drive_armature if gravcomp else self.phys.joint_armature
                attrs.update(damping=repr(float(damping)), armature=repr(float(armature)))
                if friction > 0:
                    attrs["frictionloss"] = repr(float(friction) * self.phys.joint_friction_scale)
                    attrs["solimpfriction"] = _fmt(self.phys.joint_friction_solimp)
                ET.SubElement(el, "joint", **attrs)
                art.joints.append(jn)
            for child in by_parent.get(link, []):
                add_link(el, child.child, child.pose, child)
            return el

        root_el = add_link(parent, root, pose, None)
        if root_mode == "mocap":
            root_el.set("mocap", "true")
        elif root_mode == "free":
            root_el.insert(0, ET.Element("freejoint", name=f"{prefix}/root"))
        elif root_mode != "world":
            raise ValueError(root_mode)
        return art

    def _link_contents(self, el, link, colours, material: sc.Material, what: str, folder: str) -> None:
        inertial = link.find("inertial")
        if inertial is not None:
            o = _origin(inertial)
            i = inertial.find("inertia")
            mass = float(inertial.find("mass").get("value"))
            g = {k: float(i.get(k, 0)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz")}
            tensor = np.array([[g["ixx"], g["ixy"], g["ixz"]], [g["ixy"], g["iyy"], g["iyz"]],
                               [g["ixz"], g["iyz"], g["izz"]]])
            r = quat_to_mat(o[3:])
            t = r @ tensor @ r.T  # the inertial frame's rotation, folded into the tensor
            ET.SubElement(el, "inertial", pos=_fmt(o[:3]), mass=repr(max(mass, 1e-6)),
                          fullinertia=_fmt([t[0, 0], t[1, 1], t[2, 2], t[0, 1], t[0, 2], t[1, 2]]))
        for kind in ("collision", "visual"):
            for part in link.findall(kind):
                g = self._urdf_geometry(part.find("geometry"), what, folder)
                pose = _origin(part)
                geom = self._geom(el, g, pose, what)
                if kind == "collision":
                    self._collision(geom, material)
                else:
                    self._visual(geom, self._urdf_colour(part, colours))

    @staticmethod
    def _urdf_colour(part, colours) -> tuple[float, ...]:
        m = part.find("material")
        if m is None:
            return (0.7, 0.7, 0.7, 1.0)
        c = m.find("color")
        if c is not None:
            return tuple(float(v) for v in c.get("rgba").split())
        return colours.get(m.get("name"), (0.7, 0.7, 0.7, 1.0))

    @staticmethod
    def _urdf_geometry(geo, what: str, folder: str):
        if geo is None or len(geo) == 0:
            raise BadCommand(f"{what}: a visual or collision element without geometry")
        g = geo[0]
        if g.tag == "box":
            return sc.Box(tuple(float(v) / 2 for v in g.get("size").split()))
        if g.tag == "sphere":
            return sc.Sphere(float(g.get("radius")))
        if g.tag == "cylinder":  # URDF cylinders lie along z: turn cab's x-axis cylinder back
            return _ZCylinder(float(g.get("radius")), float(g.get("length")) / 2)
        if g.tag == "mesh":
            scale = tuple(float(v) for v in g.get("scale", "1 1 1").split())
            return sc.Mesh(os.path.join(folder, g.get("filename")), scale=scale)  # relative to the URDF
        raise BadCommand(f"{what}: unsupported URDF geometry <{g.tag}>")

    # robot ------------------------------------------------------------------------------------------
    def _robot(self, world, emb: EmbodimentSpec, material: sc.Material) -> None:
        base = _pose_or_bad(emb.base_pose, "embodiment base pose")
        art = self._urdf(world, ROBOT, emb.urdf, base, "world", material, gravcomp=True)
        self.plan.robot = art
        active = {j.split("/", 1)[1] for j in art.joints}
        order = emb.joint_order()
        missing = [n for n in order if n not in active]
        if missing:
            raise BadCommand(f"embodiment {emb.name!r}: joints {missing} are not active joints of {emb.urdf}")
        extra = sorted(active - set(order))
        gripper = {j for arm in emb.arms.values() for j in arm.gripper.joints}
        act = ET.SubElement(self.root, "actuator")
        for n in order + extra:  # joints outside joint_order hold their start (as on SAPIEN)
            kp, kd = ((emb.gripper_stiffness, emb.gripper_damping) if n in gripper
                      else (emb.drive_stiffness, emb.drive_damping))
            ET.SubElement(act, "general", name=f"{ROBOT}/{n}", joint=f"{ROBOT}/{n}", gaintype="fixed",
                          gainprm=repr(float(kp)), biastype="affine", biasprm=_fmt([0.0, -kp, -kd]),
                          ctrllimited="false")
            self.plan.actuators.append(n)
        # collision filter: links of one arm, and each arm with the robot's other links
        owner = {link: name for name, arm in emb.arms.items() for link in arm.links}
        names = list(art.links)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                oa, ob = owner.get(a), owner.get(b)
                if (oa is not None or ob is not None) and (oa == ob or oa is None or ob is None):
                    self._excludes.append((art.links[a], art.links[b]))

    def _camera(self, world, spec: sc.CameraSpec, bodies: dict[str, ET.Element]) -> None:
        check_camera_spec(spec, self.plan.cameras)
        local = _pose_or_bad(spec.pose, f"camera {spec.name!r}: pose")
        body = camera_mount(spec, self.plan.robot.links if self.plan.robot else {})
        parent = world if body is None else bodies[body]
        ET.SubElement(parent, "camera", name=spec.name, mode="fixed", pos=_fmt(local[:3]),
                      quat=_fmt(quat_mul(local[3:], _MJ_CAM_FROM_CV)), fovy=repr(float(spec.fovy_deg)))
        self.plan.cameras[spec.name] = Camera(spec, body, local)

    def write(self, scene: sc.SceneSpec, emb: EmbodimentSpec, timestep: float) -> Plan:
        check_object_names(scene)
        cameras = list(scene.cameras) + list(emb.cameras)
        self._options(scene, timestep, cameras)
        world = ET.SubElement(self.root, "worldbody")
        ground = ET.SubElement(world, "geom", name="ground", type="plane", size="0 0 1",
                               pos=_fmt([0.0, 0.0, scene.ground_z]))
        self._collision(ground, scene.default_material)
        ground.set("group", str(VISUAL_GROUP))
        ground.set("rgba", _fmt(srgb(scene.ground_color)))
        self._lights(world, scene)
        for body in scene.bodies:
            self._body(world, body)
        default = scene.default_material
        for obj in scene.articulations:
            self._articulated_object(world, obj, default)
        self._robot(world, emb, default)
        bodies = {el.get("name"): el for el in world.iter("body")}
        for spec in cameras:
            self._camera(world, spec, bodies)
        if self._excludes:
            contact = ET.SubElement(self.root, "contact")
            for a, b in self._excludes:
                ET.SubElement(contact, "exclude", body1=a, body2=b)
        self.plan.xml = ET.tostring(self.root, encoding="unicode")
        return self.plan

    def _articulated_object(self, world, obj: sc.ArticulatedObject, default: sc.Material) -> None:
        pose = _pose_or_bad(obj.pose, f"articulated object {obj.name!r}: pose")
        art = self._urdf(world, obj.name, obj.urdf, pose, "mocap" if obj.fix_root else "free", default,
                         joint_damping=obj.joint_damping if obj.joint_damping > 0 else None,
                         joint_friction=obj.joint_friction if obj.joint_friction > 0 else None)
        self.plan.articulations[obj.name] = art


