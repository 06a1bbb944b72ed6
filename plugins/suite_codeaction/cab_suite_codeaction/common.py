"""Scene pieces shared by the CodeActionBench tasks: table, wall, lighting, the seeded pose sampler,
generated assets (OBJ meshes, URDFs) and a small base class.

World frame (FACTS B.2): metres, z up, ground at z = 0, +y away from the robot toward the wall,
-x on the left arm's side; quaternions are (w, x, y, z). The head camera and the robot belong to the
embodiment, not to the task scene.
"""
from __future__ import annotations

import hashlib
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from cab_core.contracts.checkpoints import SpatialRule
from cab_core.errors import CabError, PluginError
from cab_core.geometry import euler_quat, quat_mul, quat_normalize, quat_to_mat
from cab_core.contracts.scene import Body, Box, Capsule, Cylinder, Lighting, Material, Mesh, SceneSpec, Shape, Sphere, cache_dir
from cab_core.contracts.task import SceneInstance, Task, TaskInfo, ToolCaller, rng_for
from cab_core.contracts.verifier import Evaluation, Margin, Verifier, WorldView, margin_above, margin_all

from .catalog import has_catalog_entry, task_info

# --- world constants (FACTS B.2) ---------------------------------------------------------------
TABLE_TOP_Z = 0.74
TABLE_SIZE = (1.2, 0.7, 0.05)  # x, y, thickness
WALL_CENTER = (0.0, 1.0, 1.5)
WALL_HALF_SIZE = (3.0, 0.6, 1.5)  # near face at y = 0.4
DEFAULT_SPAWN_Z = 0.741  # rand_pose's default z
DESTRUCTIVE_DROP = 0.08  # a guarded object below table_z - 0.08 is knocked off (FACTS A.13)
ARMS = ("left", "right")


class LayoutError(CabError):
    """No layout satisfying a task's placement constraints was found."""


# --- colours -----------------------------------------------------------------------------------
def srgb(r: float, g: float, b: float, a: float = 1.0) -> tuple[float, float, float, float]:
    """Linear RGBA (what :class:`Material` holds) from display sRGB components in 0..1."""
    def lin(c: float) -> float:
        return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4

    return (round(lin(r), 5), round(lin(g), 5), round(lin(b), 5), a)


def material(rgb: Sequence[float], *, roughness: float = 0.6, metallic: float = 0.0, friction: float = 0.5) -> Material:
    """A material of the display-sRGB colour ``rgb`` whose static and dynamic friction are both
    ``friction`` (the defaults are :class:`Material`'s)."""
    return Material(color=srgb(*rgb), roughness=roughness, metallic=metallic, static_friction=friction,
                    dynamic_friction=friction)


WOOD = Material(color=srgb(0.66, 0.47, 0.30), roughness=0.7)
WOOD_DARK = Material(color=srgb(0.42, 0.28, 0.16), roughness=0.7)
WALL = Material(color=srgb(0.86, 0.86, 0.84), roughness=0.9)
RED = Material(color=srgb(0.85, 0.10, 0.10), roughness=0.5)
GREEN = Material(color=srgb(0.10, 0.70, 0.15), roughness=0.5)
BLUE = Material(color=srgb(0.10, 0.25, 0.90), roughness=0.5)


# --- table, wall, lighting ---------------------------------------------------------------------
def table_top_z(z_bias: float = 0.0) -> float:
    return TABLE_TOP_Z + z_bias


def table(x_bias: float = 0.0, z_bias: float = 0.0, legs: bool = True) -> Body:
    """The static table ``"table"``: a 1.2 x 0.7 x 0.05 m top whose surface is at 0.74 + z_bias,
    centred at (x_bias, 0); optional legs down to the ground (same body)."""
    sx, sy, th = TABLE_SIZE
    top = table_top_z(z_bias)
    shapes = [Shape(Box((sx / 2, sy / 2, th / 2)), material=WOOD)]
    if legs:
        leg_h = top - th
        for lx in (-1, 1):
            for ly in (-1, 1):
                shapes.append(Shape(
                    Box((0.025, 0.025, leg_h / 2)),
                    pose=(lx * (sx / 2 - 0.06), ly * (sy / 2 - 0.06), -th / 2 - leg_h / 2, 1.0, 0.0, 0.0, 0.0),
                    material=WOOD_DARK))
    return Body("table", shapes, pose=(x_bias, 0.0, top - th / 2, 1.0, 0.0, 0.0, 0.0), kind="static")


def wall() -> Body:
    """The static back wall ``"wall"``: centre (0, 1, 1.5), half-size (3, 0.6, 1.5); near face y = 0.4."""
    return Body("wall", [Shape(Box(WALL_HALF_SIZE), material=WALL)], pose=(*WALL_CENTER, 1.0, 0.0, 0.0, 0.0),
                kind="static")


def lighting() -> Lighting:
    """Ambient 0.5, one directional light, point lights at (+-1, 0, 1.8) (FACTS B.2)."""
    return Lighting(
        ambient=(0.5, 0.5, 0.5),
        directional=(((0.0, 0.5, -1.0), (0.5, 0.5, 0.5)),),
        points=(((1.0, 0.0, 1.8), (1.0, 1.0, 1.0)), ((-1.0, 0.0, 1.8), (1.0, 1.0, 1.0))),
    )


def base_scene(table_x: float = 0.0, table_z_bias: float = 0.0, legs: bool = True) -> SceneSpec:
    """Table + wall + lighting at the benchmark's 1/250 s timestep."""
    return SceneSpec(bodies=[table(table_x, table_z_bias, legs), wall()], lighting=lighting(),
                     timestep=1.0 / 250.0)


# --- sampling ----------------------------------------------------------------------------------
def rand_pose(rng: np.random.Generator, xlim: Sequence[float], ylim: Sequence[float],
              zlim: Sequence[float] = (DEFAULT_SPAWN_Z,), *, ylim_prop: bool = False,
              rotate_rand: bool = False, rotate_lim: Sequence[float] = (0.0, 0.0, 0.0),
              qpos: Sequence[float] = (1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    """RoboTwin's ``rand_pose`` (FACTS B.5) over ``rng``: uniform x, y, z in their limits (a
    one-element limit is fixed); with ``ylim_prop``, while |x| < 0.15 and y > 0, y is redrawn in
    [ylim[0], 0]; the random Euler rotation (static x-y-z, each within +-rotate_lim) is composed
    after the base quaternion ``qpos`` (in its local frame). Returns [x, y, z, qw, qx, qy, qz]."""
    def uni(lim: Sequence[float]) -> float:
        lim = tuple(float(v) for v in lim)
        return lim[0] if len(lim) == 1 else float(rng.uniform(lim[0], lim[1]))

    x, y = uni(xlim), uni(ylim)
    while ylim_prop and abs(x) < 0.15 and y > 0:
        y = float(rng.uniform(float(ylim[0]), 0.0))
    z = uni(zlim)
    q = quat_normalize(qpos)
    if rotate_rand:
        angles = [float(rng.uniform(-lim, lim)) if lim > 0 else 0.0 for lim in rotate_lim]
        q = quat_normalize(quat_mul(q, euler_quat(*angles)))
    if q[0] < 0:
        q = -q
    return np.array([x, y, z, *q], dtype=float)


def draw_variant(rng: np.random.Generator, variants: Any, ids: Sequence[int] | None = None) -> tuple[int, Any]:
    """A model id drawn uniformly from ``ids`` (by default every index of the sequence ``variants``)
    with one ``rng.integers`` draw, and its entry in ``variants``."""
    ids = range(len(variants)) if ids is None else ids
    model_id = int(ids[int(rng.integers(0, len(ids)))])
    return model_id, variants[model_id]


def sample_until(draw: Callable[[], np.ndarray], accept: Callable[[np.ndarray], bool], *,
                 what: str, max_tries: int = 10_000) -> np.ndarray:
    """Redraw until ``accept`` holds (RoboTwin's resample-until loops), failing loudly."""
    for _ in range(max_tries):
        p = draw()
        if accept(p):
            return p
    raise LayoutError(f"no valid placement for {what} after {max_tries} draws")


def yaw_of(q: Sequence[float]) -> float:
    """Heading (rotation about world z) of the body's local x axis."""
    m = quat_to_mat(q)
    return float(np.arctan2(m[1, 0], m[0, 0]))


def pose_list(p: Iterable[float]) -> list[float]:
    """A pose (or any vector) as a JSON-friendly list of floats rounded to the micrometre."""
    return [round(float(v), 6) for v in p]


vec = pose_list


# --- geometry of shape lists -------------------------------------------------------------------
def lowest_point_z(shapes: Sequence[Shape], quat: Sequence[float] = (1.0, 0.0, 0.0, 0.0)) -> float:
    """Lowest z, in a frame rotated by ``quat`` about the body origin, over all collision shapes
    (boxes, spheres, capsules, cylinders). The body rests on a plane at height h when its origin
    is at h - lowest_point_z(...)."""
    r_body = quat_to_mat(quat)
    low = np.inf
    for s in shapes:
        if not s.collision:
            continue
        r = r_body @ quat_to_mat(s.pose[3:7])
        c = r_body @ np.asarray(s.pose[:3], dtype=float)
        g = s.geometry
        if isinstance(g, Box):
            h = np.asarray(g.half_size)
            low = min(low, c[2] - float(np.abs(r[2, :]) @ h))
        elif isinstance(g, Sphere):
            low = min(low, c[2] - g.radius)
        elif isinstance(g, Capsule):
            low = min(low, c[2] - abs(r[2, 0]) * g.half_length - g.radius)
        elif isinstance(g, Cylinder):
            az = abs(r[2, 0])  # axis along local x
            low = min(low, c[2] - az * g.half_length - g.radius * np.sqrt(max(0.0, 1 - az * az)))
        else:
            raise TypeError(f"lowest_point_z does not handle {type(g).__name__}")
    return float(low)


# --- generated assets --------------------------------------------------------------------------
IDENTITY_Q = (1.0, 0.0, 0.0, 0.0)


def body_pose(xyz: Sequence[float], quat: Sequence[float] = IDENTITY_Q) -> tuple[float, ...]:
    """A pose (x, y, z, qw, qx, qy, qz) as a tuple of floats."""
    return tuple(float(v) for v in (*xyz, *quat))


def trimesh_module() -> Any:
    """``trimesh``, imported on first use: only building a scene's assets needs it."""
    import trimesh

    return trimesh


def assets_dir() -> Path:
    p = cache_dir() / "assets"
    p.mkdir(parents=True, exist_ok=True)
    return p


def write_asset(stem: str, data: bytes, suffix: str) -> Path:
    """Store ``data`` as ``<cache>/assets/<stem>-<sha256[:12]><suffix>``: content-addressed (the same
    content always gets the same name) and written atomically (temp file + rename), so concurrent
    builders never see a partial file."""
    digest = hashlib.sha256(data).hexdigest()[:12]
    path = assets_dir() / f"{stem}-{digest}{suffix}"
    if path.is_file() and path.stat().st_size == len(data):
        return path
    fd, tmp = tempfile.mkstemp(prefix=f".{stem}-", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def mesh_asset(stem: str, mesh: Any) -> str:
    """Write a ``trimesh.Trimesh`` as an OBJ asset; returns its path (for :class:`Mesh`)."""
    data = mesh.export(file_type="obj", include_normals=True).encode("utf-8")
    return str(write_asset(stem, data, ".obj"))


def mesh_shape(stem: str, mesh: Any, *, convex: bool = True, **shape_kw: Any) -> Shape:
    return Shape(Mesh(mesh_asset(stem, mesh), convex=convex), **shape_kw)


def urdf_asset(stem: str, text: str) -> str:
    """Write a URDF (which refers to other assets by bare file name, in the same folder)."""
    return str(write_asset(stem, text.encode("utf-8"), ".urdf"))


# --- URDF text helpers --------------------------------------------------------------------------
def _f(v: Iterable[float]) -> str:
    return " ".join(f"{float(x):.6g}" for x in v)


def urdf_geometry(kind: str, dims: Sequence[float]) -> str:
    if kind == "box":
        return f'<box size="{_f(dims)}"/>'
    if kind == "cylinder":  # URDF cylinders lie along the link's z axis
        return f'<cylinder radius="{float(dims[0]):.6g}" length="{float(dims[1]):.6g}"/>'
    if kind == "sphere":
        return f'<sphere radius="{float(dims[0]):.6g}"/>'
    raise ValueError(kind)


def urdf_part(kind: str, dims: Sequence[float], xyz: Sequence[float], *, rgba: Sequence[float],
              rpy: Sequence[float] = (0.0, 0.0, 0.0), material: str, collision: bool = True,
              visual: bool = True) -> str:
    """One primitive of a link, as visual and/or collision elements."""
    origin = f'<origin xyz="{_f(xyz)}" rpy="{_f(rpy)}"/>'
    geom = f"<geometry>{urdf_geometry(kind, dims)}</geometry>"
    out = []
    if visual:
        out.append(f'<visual>{origin}{geom}<material name="{material}"><color rgba="{_f(rgba)}"/>'
                   f"</material></visual>")
    if collision:
        out.append(f"<collision>{origin}{geom}</collision>")
    return "\n    ".join(out)


def urdf_inertial(mass: float, com: Sequence[float], diag: Sequence[float]) -> str:
    ixx, iyy, izz = (max(float(v), 1e-7) for v in diag)
    return (f'<inertial><origin xyz="{_f(com)}" rpy="0 0 0"/><mass value="{mass:.6g}"/>'
            f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>')


def hinged_urdf(robot: str, *, base_inertial: str, base_parts: Sequence[str], child: str, child_inertial: str,
                child_parts: Sequence[str], joint: str, origin: Sequence[float], axis: str, upper: float,
                velocity: float, damping: float, friction: float) -> str:
    """A two-link URDF: a ``base`` link and a ``child`` link on one revolute ``joint`` (lower limit 0)."""
    nl = "\n    "
    ox, oy, oz = origin
    _one_colour_per_material(robot, [*base_parts, *child_parts])
    return f"""<?xml version="1.0"?>
<robot name="{robot}">
  <link name="base">
    {base_inertial}
    {nl.join(base_parts)}
  </link>
  <link name="{child}">
    {child_inertial}
    {nl.join(child_parts)}
  </link>
  <joint name="{joint}" type="revolute">
    <parent link="base"/>
    <child link="{child}"/>
    <origin xyz="{ox:.6g} {oy:.6g} {oz:.6g}" rpy="0 0 0"/>
    <axis xyz="{axis}"/>
    <limit lower="0" upper="{upper}" effort="100" velocity="{velocity}"/>
    <dynamics damping="{damping}" friction="{friction}"/>
  </joint>
</robot>
"""


def _one_colour_per_material(robot: str, parts: Sequence[str]) -> None:
    """A URDF material name is global to the robot: simulators keep the first or the last colour
    given under a name, so two colours under one name would render differently per simulator."""
    seen: dict[str, str] = {}
    for name, rgba in re.findall(r'<material name="([^"]+)"><color rgba="([^"]+)"/>', "".join(parts)):
        if seen.setdefault(name, rgba) != rgba:
            raise ValueError(f"{robot}: material {name!r} is given two colours ({seen[name]} and {rgba}); "
                             "name each colour's material apart")


def box_inertia(mass: float, size: Sequence[float]) -> tuple[float, float, float]:
    x, y, z = size
    return (mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12, mass * (x * x + y * y) / 12)


# --- verifiers ---------------------------------------------------------------------------------
def grippers_open(w: WorldView, arms: Iterable[str], threshold: float) -> tuple[bool, dict[str, float], Margin]:
    """Whether every one of ``arms`` has its gripper commanded open (above ``threshold``); the
    commands as values (``gripper_<arm>``); the margin (the least open gripper's, each against the
    band above the threshold)."""
    grips = {a: w.gripper_command(a) for a in arms}
    return (all(g > threshold for g in grips.values()), {f"gripper_{a}": float(g) for a, g in grips.items()},
            margin_all(*(margin_above(g, threshold, "gripper command", 1 - threshold) for g in grips.values())))


class GrippersOpenVerifier(Verifier):
    """A final-state verifier whose success needs the task's own predicates (``measure``) and,
    recorded after them, ``grippers_open``: every one of ``arms`` has its gripper commanded above
    ``open_threshold``."""

    arms: Sequence[str] = ARMS
    open_threshold: float = 0.8

    def measure(self, w: WorldView) -> tuple[dict[str, bool], dict[str, float], dict[str, Margin]]:
        """The task's own predicates, the values measured and the predicates' margins."""
        raise NotImplementedError

    def evaluate(self, w: WorldView) -> Evaluation:
        preds, values, margins = self.measure(w)
        preds["grippers_open"], grips, margins["grippers_open"] = grippers_open(w, self.arms, self.open_threshold)
        values.update(grips)
        return Evaluation(success=all(preds.values()), predicates=preds, values=values, margins=margins)


class LatchVerifier(Verifier):
    """A verifier scored by latch: the attempt succeeds once ``holds`` is true, polled at every
    physics step."""

    scoring = "latch"
    poll_every = 1


# --- spatial checkpoints -------------------------------------------------------------------------
def lift_rules(info: dict, initial_z: float) -> list[SpatialRule]:
    """"Lift left" and "Lift right" (after rules 0 and 1, the two arms' approaches): each arm's TCP
    rises by the lift the task asks for, from ``initial_z`` to ``info["raised_z"]`` (in cm)."""
    lift = max(0.0, 100.0 * (float(info["raised_z"]) - float(initial_z)))
    return [SpatialRule("Lift left", "left", None, None, prerequisites=(0,), lift_above_cm=lift),
            SpatialRule("Lift right", "right", None, None, prerequisites=(1,), lift_above_cm=lift)]


# --- task base ---------------------------------------------------------------------------------
def arm_names(embodiment: Any) -> list[str]:
    """The embodiment's arm names (tasks read declarations, never a robot's name)."""
    arms = getattr(embodiment, "arms", None)
    return sorted(arms) if arms else list(ARMS)


def _body_radius(body: Body) -> float:
    """How far a body reaches from its origin in the table plane, roughly (a mesh: 0.15 m)."""
    r = 0.0
    for s in body.shapes:
        g = s.geometry
        off = float(np.linalg.norm(np.asarray(s.pose[:2], float)))
        if isinstance(g, Box):
            r = max(r, off + float(np.linalg.norm(g.half_size[:2])))
        elif isinstance(g, (Cylinder, Sphere, Capsule)):
            r = max(r, off + float(g.radius) + (float(g.half_length) if isinstance(g, Capsule) else 0.0))
        else:
            r = max(r, off + 0.15)
    return r


class CodeActionTask(Task):
    """A catalog task of this suite: ``name`` selects the catalog entry (instruction, seed,
    scoring, budgets); unless a subclass sets it, it is the name of the subclass's module (the
    suite's task modules are named after their catalog entries). A task of another package that
    reuses this class declares its own metadata, ``info = TaskInfo(...)`` on its class (or
    ``self.info`` set in its own ``__init__``); one that does neither, and whose name is not in
    the catalog, is refused in one line saying so. A task lays out its objects on
    the base scene (``lay_out``), names its verifier (``verifier_class``) and its subgoals'
    predicates (``subgoal_predicates``), and writes its reference solution (``oracle``)."""

    name: str = ""
    #: the task's verifier class, built from a scene's info (``verifier`` and ``evaluate`` use it)
    verifier_class: type[Verifier]
    #: the catalog's subgoals, in order: each holds when all of these verifier predicates do
    subgoal_predicates: tuple[tuple[str, ...], ...] = ()
    #: the table's placement in the base scene (``base_scene``)
    table_x: float = 0.0
    table_z_bias: float = 0.0
    #: held out from the seeds the suite was developed on (the catalog's, 0-9): the oracle succeeds
    #: at each within budgets on every simulator, and under small perturbations (cab-suite-check
    #: --seed-set heldout [--perturb N])
    seed_sets = {"heldout": tuple(range(100, 120))}

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if not cls.__dict__.get("name"):
            cls.name = cls.__module__.rsplit(".", 1)[-1]

    def __init__(self) -> None:
        declared = getattr(type(self), "info", None)
        if isinstance(declared, TaskInfo):  # a task outside the catalog declares its own metadata
            self.info = declared
            return
        if not has_catalog_entry(self.name):
            cls = type(self)
            raise PluginError(
                f"task {self.name!r} ({cls.__module__}.{cls.__qualname__}, a CodeActionTask) has no metadata: "
                "the suite's catalog, which gives its own tasks theirs, has no entry of that name; declare it "
                "on the class as info = TaskInfo(name=..., instruction=..., seed=..., scoring=..., "
                "budget_tool_calls=..., budget_sim_s=...) (cab_core.contracts.task; or set self.info in "
                "__init__, as examples/block_on_pad does)")
        self.info: TaskInfo = task_info(self.name)

    def build(self, seed: int, embodiment: Any = None) -> SceneInstance:
        """The base scene (table, wall, lighting) with the objects ``lay_out`` adds; the info starts
        with the task, the seed and the table top's height, followed by what ``lay_out`` returns."""
        top = table_top_z(self.table_z_bias)
        scene = base_scene(self.table_x, self.table_z_bias)
        info = self.lay_out(rng_for(seed, self.name), top, scene, embodiment)
        return SceneInstance(scene=scene, info={"task": self.name, "seed": int(seed), "table_top_z": top, **info})

    def lay_out(self, rng: np.random.Generator, top: float, scene: SceneSpec, embodiment: Any) -> dict[str, Any]:
        """Add the task's objects to ``scene``, drawing their layout from ``rng`` (the table top is at
        height ``top``); returns what the scene's info records about them."""
        raise NotImplementedError(f"{self.name} lays out no scene")

    def verifier(self, instance: SceneInstance) -> Verifier:
        return self.verifier_class(instance.info)

    def evaluate(self, w: WorldView) -> Evaluation:
        """The verifier's evaluation of the world as ``w`` sees it now."""
        return self.verifier_class(w.info).evaluate(w)

    def subgoals(self, w: WorldView) -> list[bool]:
        """The catalog's subgoals as ``w`` sees the world now (``subgoal_predicates``)."""
        p = self.evaluate(w).predicates
        return [all(p[n] for n in names) for names in self.subgoal_predicates]

    def oracle(self, call: ToolCaller, world: WorldView) -> None:
        """The reference solution from any reachable state (:func:`..oracle.resume`): what is
        already achieved is not done again, hands an earlier agent left busy are cleared first,
        and a state it cannot complete from is reported (``NotRecoverable``) with its reason."""
        from .oracle import resume

        resume(self, call, world)

    #: free places for distractor objects (appearance randomisation): the back corners of the part
    #: of the table the head camera sees, far from the robot, (x offset from the table's centre,
    #: y); each kept only where no object of the instance is near
    DISTRACTOR_PLACES = ((-0.36, 0.26), (0.36, 0.26), (-0.30, 0.14), (0.30, 0.14))
    DISTRACTOR_CLEARANCE = 0.12  # m between a distractor's place and the reach of any object of the task

    def distractor_slots(self, instance: SceneInstance) -> list[tuple[float, float, float]]:
        top = float(instance.info["table_top_z"])
        reach = [(np.asarray(b.pose[:2], float), _body_radius(b)) for b in instance.scene.bodies
                 if b.name not in ("table", "wall")]
        reach += [(np.asarray(a.pose[:2], float), 0.3) for a in instance.scene.articulations]
        out = []
        for dx, y in self.DISTRACTOR_PLACES:
            p = np.array([self.table_x + dx, y])
            if all(np.linalg.norm(p - c) > r + self.DISTRACTOR_CLEARANCE for c, r in reach):
                out.append((float(p[0]), float(p[1]), top))
        return out

    def keeps_hands(self, world: WorldView) -> bool:
        """Whether ``solve`` goes on from the hands as they are now (holding, closed, away from
        their start); False: :func:`..oracle.resume` puts down what is held and takes the hands back
        to their start first."""
        return False

    def not_recoverable(self, world: WorldView) -> tuple[str, str] | None:
        """``(kind, reason)`` when ``solve`` cannot start from this state (kinds:
        ``cab_core.contracts.task.NOT_RECOVERABLE_KINDS``), e.g. an object it takes standing lies
        on its side; None: it can."""
        return None

    def solve(self, call: ToolCaller, world: WorldView) -> None:
        """The reference solution from the scene's start (or a state like it: objects where they
        can be taken, hands free), its targets computed from the objects' poses now."""
        raise NotImplementedError(f"the reference solution of {self.name} is not written yet")

    def __repr__(self) -> str:
        return f"<task {self.name}>"
