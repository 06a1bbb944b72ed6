"""Tool contract (registry, schemas, validation) and the geometry/observation handlers over a
synthetic RobotContext (a fake simulator with the real head-camera calibration)."""
from __future__ import annotations

import json
import math
import sys
import typing

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, Field

from cab_core import geometry as gt
from cab_core.contracts.embodiment import ArmSpec, EmbodimentSpec, GripperSpec
from cab_core.contracts.simulator import Contact
from cab_core.errors import PluginError, ToolArgumentError
from cab_core.geometry import intrinsics, mat_to_quat, pose_mul, pose_to_mat, quat_to_mat
from cab_core.tools import CATALOG as DECLARED
from cab_core.tools import DONE, RUN_CODE, TOOLS, build_registry, estimate, motion, observe, schemas, validate_args
from cab_core.tools import models as m
from cab_core.tools.context import ObservationStore, RobotContext
from cab_core.tools.registry import ToolDef, tool

# -- the tool list ---------------------------------------------------------------------------------
# The core's list (tools/__init__.py CATALOG) is the registry's source; the suite's tests compare
# their catalog with it (plugins/suite_codeaction/tests/test_catalog_tools.py).
HOST_TOOLS = [RUN_CODE.name, DONE.name]  # served by the episode host: no handler
ROBOT_TOOLS = [n for n in TOOLS if n not in HOST_TOOLS]


def test_registry_is_the_core_tool_list_in_order():
    assert list(TOOLS) == [e.name if isinstance(e, ToolDef) else e.__name__ for e in DECLARED]
    assert len(TOOLS) == len(DECLARED) == len(ROBOT_TOOLS) + 2
    assert list(TOOLS)[-2:] == HOST_TOOLS


@pytest.mark.parametrize("name", list(TOOLS))
def test_flags_follow_the_kind_and_group(name):
    t = TOOLS[name]
    assert t.charged == (t.kind != "done")
    assert t.advances_physics == (t.kind == "act")
    if t.group == "motion":  # every motion tool acts (consumes simulated time)
        assert t.advances_physics
    if t.advances_physics:
        assert t.destructive and not t.read_only
    elif t.group in ("observation", "geometry"):
        assert t.read_only and not t.destructive
    if t.renders:  # a fresh image: an observation tool, or a geometry tool that captures one
        assert t.group in ("observation", "geometry") and t.result is not None
    if name in HOST_TOOLS:  # served by the episode host
        assert t.handler is None and t.kind in ("code", "done")
    else:
        assert t.handler.__name__ == t.name and t.handler.tool_def is t


@pytest.mark.parametrize("name", list(TOOLS))
def test_schema_generates_and_documents_every_field(name):
    s = TOOLS[name].json_schema()
    assert s["type"] == "object" and s["additionalProperties"] is False
    for prop, body in s.get("properties", {}).items():
        assert body.get("description"), f"{name}.{prop} has no description"
    for sub in s.get("$defs", {}).values():
        for body in sub["properties"].values():
            assert body.get("description")
    assert len(TOOLS[name].description) > 80


def test_schemas_are_json_and_complete():
    out = schemas()
    json.dumps(out)
    assert [s["name"] for s in out] == list(TOOLS)
    assert set(out[0]) == {"name", "description", "group", "read_only", "destructive", "advances_physics",
                           "charged", "parameters"}


def test_registration_refuses_an_undocumented_argument():
    class Bad(BaseModel):
        model_config = ConfigDict(extra="forbid")
        arm: str = Field(description="ok")
        x: float

    with pytest.raises(PluginError, match="Bad.x"):
        build_registry([ToolDef(name="bad", group="geometry", kind="read", args=Bad, description="d")])

    class Inner(BaseModel):
        y: int

    class Outer(BaseModel):
        model_config = ConfigDict(extra="forbid")
        items: list[Inner] = Field(description="nested")

    with pytest.raises(PluginError, match="Inner.y"):
        build_registry([ToolDef(name="bad", group="geometry", kind="read", args=Outer, description="d")])


def test_build_registry_is_fresh_and_cached_view_is_read_only():
    assert list(build_registry()) == list(TOOLS)
    with pytest.raises(TypeError):
        TOOLS["x"] = None  # type: ignore[index]


def test_each_tool_is_declared_once_next_to_its_handler():
    """The registry's handler is the function itself, declared in its own module with @tool; its
    docstring is the description; only run_code and done (served by the host) have none."""
    handlers = [e for e in DECLARED if not isinstance(e, ToolDef)]
    assert [e for e in DECLARED if isinstance(e, ToolDef)] == [RUN_CODE, DONE]
    assert {h.__module__ for h in handlers} == {observe.__name__, estimate.__name__, motion.__name__}
    for h in handlers:
        assert getattr(sys.modules[h.__module__], h.__name__) is h is TOOLS[h.__name__].handler
        assert TOOLS[h.__name__].description == " ".join(h.__doc__.split())
    declared = {f.__name__ for mod in (observe, estimate, motion) for f in vars(mod).values()
                if callable(f) and isinstance(getattr(f, "tool_def", None), ToolDef)}
    assert declared == {h.__name__ for h in handlers}  # no declared handler left out of the catalog


def test_each_tools_models_sit_beside_its_handler():
    """A tool's argument model is defined in its handler's module, and so is its result model unless
    several modules share it (tools/models.py); run_code's and done's beside their declarations."""
    for name in ROBOT_TOOLS:
        t = TOOLS[name]
        assert t.args.__module__ == t.handler.__module__, name
        if t.result is not None:
            assert t.result.__module__ in (t.handler.__module__, m.__name__), name
    for t in (RUN_CODE, DONE):
        assert t.args.__module__ == t.result.__module__ == "cab_core.tools"


def test_a_handlers_argument_model_is_the_annotation_of_its_args_parameter():
    """The registry reads each tool's argument model from its handler's ``args`` annotation."""
    handlers = [e for e in DECLARED if not isinstance(e, ToolDef)]
    for h in handlers:
        assert TOOLS[h.__name__].args is typing.get_type_hints(h, localns={"RobotContext": RobotContext})["args"]
        assert issubclass(TOOLS[h.__name__].args, BaseModel)

    def unannotated(ctx, args):
        """Reads nothing."""

    with pytest.raises(TypeError, match=r"tool unannotated: annotate its args parameter"):
        tool(group="observation", kind="read")(unannotated)

    def not_a_model(ctx, args: dict):
        """Reads nothing."""

    with pytest.raises(TypeError, match=r"tool not_a_model: annotate its args parameter .* not <class 'dict'>"):
        tool(group="observation", kind="read")(not_a_model)

    def unresolved(ctx, args: NoSuchModel):  # noqa: F821
        """Reads nothing."""

    with pytest.raises(TypeError, match="tool unresolved: its args annotation does not resolve .*NoSuchModel"):
        tool(group="observation", kind="read")(unresolved)


def test_a_handler_without_docstring_or_outside_the_catalog_is_refused():
    def nameless(ctx, args: observe.CaptureHeadArgs):
        pass

    with pytest.raises(TypeError, match="docstring"):
        tool(group="observation", kind="read")(nameless)
    with pytest.raises(PluginError, match="not declared as a tool"):
        build_registry([nameless])
    with pytest.raises(PluginError, match="duplicate tool 'done'"):
        build_registry([DONE, DONE])


@pytest.mark.parametrize("name,raw,needle", [
    ("get_arm_pose", {}, "missing required argument 'arm'"),
    ("get_arm_pose", {"arm": "middle"}, "arm: Input should be 'left' or 'right'"),
    ("get_arm_pose", {"arm": "left", "speed": 1}, "unknown argument 'speed'"),
    ("grasp_quat_candidates", {"approach_axis_world": [0, 0, -1], "opening_axis_world": [1, 0, 0.01]}, "orthogonal"),
    ("grasp_quat_candidates", {"approach_axis_world": [0, 0, 0], "opening_axis_world": [1, 0, 0]}, "non-zero"),
    ("preview_tcp_pose", {"obs_id": "obs_0001", "arm": "left", "tcp_xyz": [0, 0, 1], "quat_wxyz": [1, 0, 0, 0],
                          "reference_px": [1, 2], "reference_xyz_world": [0, 0, 0]}, "not both"),
    ("preview_tcp_pose", {"obs_id": "obs_0001", "arm": "left", "tcp_xyz": [0, 0, 1], "quat_wxyz": [0, 0, 0, 0]},
     "quaternion must be non-zero"),
    ("draw_marks", {"obs_id": "o", "pixels": [[1, 2]], "labels": ["a", "b"]}, "one entry per pixel"),
    ("draw_marks", {"obs_id": "o", "pixels": [[1, 2]] * 13, "labels": ["a"] * 13}, "at most 12"),
    ("capture_evidence_views", {"views": ["overview", "overview"]}, "unique"),
    ("capture_evidence_views", {"views": []}, "at least 1"),
    ("capture_wrist", {"active_arm": "none"}, "views='both'"),
    ("set_gripper", {"arm": "left", "pos": 1.5}, "pos: Input should be less than or equal to 1"),
    ("plane_intersect", {"obs_id": "o", "px": [1, 2], "plane_point_xyz": [0, 0, 0.74], "plane_normal_xyz": [0, 0, 1]},
     "missing required argument 'plane_offset_sigma_m'"),
    ("probe_contact_along", {"arm": "left", "direction_xyz": [0, 0, -1], "distance_m": 0, "step_m": 0.01}, "greater than 0"),
    ("scale_from_object_size", {"obs_id": "o", "bbox": [10, 10, 5, 20], "extent_axis": "width", "known_extent_m": 0.1},
     "x1 < x2"),
    ("move_delta", {"arm": "left", "dx": float("nan")}, "finite"),
    ("compare_tcp_poses", {"obs_id": "o", "candidates": [{"arm": "left", "tcp_xyz": [0, 0, 1], "quat_wxyz": [1, 0, 0, 0]}]},
     "at least 2"),
])
def test_validation_errors_are_typed_and_readable(name, raw, needle):
    with pytest.raises(ToolArgumentError) as e:
        validate_args(name, raw)
    msg = str(e.value)
    assert msg.startswith("bad arguments: ")
    assert needle in msg
    assert len(msg) < 300


def test_unknown_tool_and_non_object_arguments():
    with pytest.raises(ToolArgumentError, match="unknown tool"):
        validate_args("teleport", {})
    with pytest.raises(ToolArgumentError, match="JSON object"):
        validate_args("move_delta", [1, 2])


def test_defaults_and_normalisation():
    a = validate_args("move_delta", {"arm": "right", "dz": 0.05})
    assert (a.dx, a.dy, a.dz, a.path) == (0.0, 0.0, 0.05, "waypoint_legs")
    assert validate_args("get_robot_state", None).arms == ["left", "right"]
    assert validate_args("capture_evidence_views", {}).views == ["overview", "left_wrist", "right_wrist"]
    q = validate_args("reach_tcp", {"arm": "left", "target_xyz": [0, 0, 1], "target_quat": [2, 0, 0, 0]}).target_quat
    assert q == [1.0, 0.0, 0.0, 0.0]
    d = validate_args("done", {"report": "r"})
    assert d.success_claim is None
    assert validate_args("camera_aim_pose", {"camera": "left_camera", "target_xyz": [0, 0, 0.75]}).pitch == 80.0


# ==============================================================================================
# a synthetic robot context
# ==============================================================================================
HEAD_E = np.array([[1, 0, 0, 0.032], [0, -0.8, -0.6, 0.45], [0, 0.6, -0.8, 1.35]], float)
HEAD_K = np.array([[717.284, 0, 320], [0, 717.284, 240], [0, 0, 1]], float)
WRIST_K = intrinsics(320, 240, 37.0)
TABLE_Z = 0.74


def cam_pose_from_E(E: np.ndarray) -> np.ndarray:
    R, t = E[:, :3], E[:, 3]
    return np.concatenate([-R.T @ t, mat_to_quat(R.T)])


def approach_y_quat() -> np.ndarray:
    """TCP approach +y (forward), opening -x, normal +z."""
    return mat_to_quat(np.stack([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], axis=1).astype(float))


# camera pose in the TCP frame: 8 cm behind, 6 cm "above" (tcp +z), looking along the approach axis
MOUNT = np.concatenate([[-0.08, 0.0, 0.06], mat_to_quat(np.stack([[0, -1, 0], [0, 0, -1], [1, 0, 0]], axis=1).astype(float))])


def make_arm(name: str, p: str) -> ArmSpec:
    return ArmSpec(name=name, joints=tuple(f"{p}_joint{i}" for i in range(1, 7)), base_link=f"{p}_base",
                   ee_link=f"{p}_link6", tcp_link=f"{p}_tcp", camera_link=f"{name}_camera",
                   gripper=GripperSpec(joints=(f"{p}_joint7", f"{p}_joint8"), finger_links=(f"{p}_link7", f"{p}_link8"),
                                       closed_target=0.0, open_target=0.045, gap_at_zero_m=0.048),
                   home_qpos=(0.0,) * 6)


class FakeSim:
    """Robot links at fixed poses, cameras from fixed calibrations, a flat grey-gradient render."""

    def __init__(self):
        self.emb = EmbodimentSpec(name="fake_dual_arm", urdf="", srdf="", base_pose=(0, 0, 0, 1, 0, 0, 0),
                                  arms={"left": make_arm("left", "fl"), "right": make_arm("right", "fr")}, cameras=())
        self.joint_names = self.emb.joint_order()
        self.qpos = np.zeros(len(self.joint_names))
        for a in ("fl", "fr"):  # each finger 0.02 m open -> gap 0.088 m
            for j in (7, 8):
                self.qpos[self.joint_names.index(f"{a}_joint{j}")] = 0.02
        self.tcp = {"left": np.concatenate([[-0.30, -0.19, 0.94], approach_y_quat()]),
                    "right": np.concatenate([[0.30, -0.19, 0.94], approach_y_quat()])}
        self.contacts: list[Contact] = []
        self.fixed = {"head_camera": cam_pose_from_E(HEAD_E)}

    def set_tcp(self, arm: str, pose) -> None:
        self.tcp[arm] = np.asarray(pose, float)

    def _finger_poses(self, arm: str, p: str) -> dict:
        T = pose_to_mat(self.tcp[arm])
        gap = 0.048 + 2 * 0.02
        out = {}
        for link, s in ((f"{p}_link7", 1), (f"{p}_link8", -1)):
            xyz = T[:3, 3] - 0.0354 * T[:3, 0] + s * gap / 2 * T[:3, 1]
            out[link] = np.concatenate([xyz, self.tcp[arm][3:]])
        return out

    def get_link_pose(self, link: str) -> np.ndarray:
        for arm, p in (("left", "fl"), ("right", "fr")):
            if link == f"{p}_tcp":
                return self.tcp[arm].copy()
            if link == f"{p}_link6":
                T = pose_to_mat(self.tcp[arm])
                return np.concatenate([T[:3, 3] - 0.12 * T[:3, 0], self.tcp[arm][3:]])
            if link == f"{p}_base":
                return np.array([-0.3 if arm == "left" else 0.3, -0.65, 0.75, 1, 0, 0, 0], float)
            fp = self._finger_poses(arm, p)
            if link in fp:
                return fp[link]
        raise KeyError(link)

    def camera_pose(self, name: str) -> np.ndarray:
        if name in self.fixed:
            return self.fixed[name].copy()
        return pose_mul(self.tcp[name.split("_")[0]], MOUNT)

    def camera_intrinsics(self, name: str) -> np.ndarray:
        return HEAD_K.copy() if name == "head_camera" else WRIST_K.copy()

    def camera_size(self, name: str) -> tuple[int, int]:
        return (480, 640) if name == "head_camera" else (240, 320)

    def render(self, name: str) -> np.ndarray:
        h, w = self.camera_size(name)
        img = np.zeros((h, w, 3), np.uint8)
        img[..., 0] = np.linspace(40, 200, w, dtype=np.uint8)[None]
        img[..., 1] = 90
        img[..., 2] = np.linspace(30, 160, h, dtype=np.uint8)[:, None]
        return img

    def get_qpos(self):
        return self.qpos.copy()

    def get_qvel(self):
        return np.zeros_like(self.qpos)

    def get_contacts(self):
        return list(self.contacts)


class FakeClock:
    steps = 0


@pytest.fixture
def ctx() -> RobotContext:
    sim = FakeSim()
    return RobotContext(sim, None, sim.emb, FakeClock(), ObservationStore())  # type: ignore[arg-type]


def call(ctx, name, **kw):
    return TOOLS[name].handler(ctx, validate_args(name, kw))


# ==============================================================================================
# geometry
# ==============================================================================================
def test_head_camera_fake_matches_the_recorded_calibration(ctx):
    o = ctx.capture("head_camera")
    assert np.allclose(o.E, HEAD_E, atol=1e-9)
    assert np.allclose(gt.camera_centre(o.E), [-0.032, -0.45, 1.35])


@pytest.mark.parametrize("px", [[320, 240], [10.5, 20.25], [600, 470], [-50, 700]])
def test_project_of_ray_round_trip(ctx, px):
    o = ctx.capture("head_camera")
    r = call(ctx, "ray", obs_id=o.obs_id, px=px).payload
    assert r["kind"] == "ray" and r["valid"] and r["frame"] == "world"
    assert r["provenance"]["pixel_in_frame"] == (0 <= px[0] < 640 and 0 <= px[1] < 480)
    origin, d = np.array(r["value"]["origin"]), np.array(r["value"]["dir"])
    assert abs(np.linalg.norm(d) - 1) < 1e-6
    p = call(ctx, "project", obs_id=o.obs_id, xyz=list(origin + 1.3 * d)).payload
    assert p["valid"] and p["kind"] == "pixel_point" and p["units"] == "px"
    assert np.allclose(p["value"], px, atol=1e-2)


def test_project_behind_camera_is_null(ctx):
    o = ctx.capture("head_camera")
    p = call(ctx, "project", obs_id=o.obs_id, xyz=[-0.032, -1.0, 1.8]).payload
    assert p["value"] is None and not p["valid"] and p["failure"]["code"] == "BEHIND_CAMERA"


def test_unknown_obs_id_is_a_typed_error(ctx):
    with pytest.raises(ToolArgumentError, match="unknown obs_id"):
        call(ctx, "ray", obs_id="obs_9999", px=[1, 2])


def test_plane_intersect_hits_the_table_at_the_projected_point(ctx):
    o = ctx.capture("head_camera")
    target = np.array([0.12, 0.05, TABLE_Z])
    px = call(ctx, "project", obs_id=o.obs_id, xyz=target.tolist()).payload["value"]
    r = call(ctx, "plane_intersect", obs_id=o.obs_id, px=px, plane_point_xyz=[0, 0, TABLE_Z],
             plane_normal_xyz=[0, 0, 2], plane_offset_sigma_m=0.0, pixel_sigma_px=0.0).payload
    assert r["valid"] and r["coarse"] and r["kind"] == "world_point"
    assert np.allclose(r["value"], target, atol=1e-5)
    assert r["uncertainty"]["sigma_m"] == 0.0
    prov = r["provenance"]
    assert prov["range_m"] == pytest.approx(np.linalg.norm(target - [-0.032, -0.45, 1.35]), abs=1e-5)
    assert {"d_du", "d_dv"} <= set(prov["pixel_jacobian_m_per_px"])


def test_plane_intersect_uncertainty_grows_with_obliquity(ctx):
    o = ctx.capture("head_camera")
    base = dict(obs_id=o.obs_id, plane_point_xyz=[0, 0, TABLE_Z], plane_normal_xyz=[0, 0, 1],
                plane_offset_sigma_m=0.005, pixel_sigma_px=2.0)
    near = call(ctx, "plane_intersect", px=[320, 450], **base).payload  # steep view of the near table
    far = call(ctx, "plane_intersect", px=[320, 60], **base).payload  # grazing view of the far table
    assert far["provenance"]["obliquity_amplification"] > near["provenance"]["obliquity_amplification"] > 1
    for term in ("pixel_m", "plane_offset_m"):
        assert far["uncertainty"]["terms"][term] > near["uncertainty"]["terms"][term]
    assert far["uncertainty"]["sigma_m"] > near["uncertainty"]["sigma_m"]
    # the same pixel against ever more tilted planes: amplification = 1 / |cos(ray, normal)|
    amps = []
    for tilt in (0, 20, 40, 60):
        n = [0, math.sin(math.radians(tilt)), math.cos(math.radians(tilt))]
        r = call(ctx, "plane_intersect", px=[320, 240], **{**base, "plane_normal_xyz": n}).payload
        c = abs(np.dot(n, r["provenance"]["ray"]["dir"]))
        assert r["provenance"]["obliquity_amplification"] == pytest.approx(1 / c, rel=1e-3)
        assert r["uncertainty"]["terms"]["plane_offset_m"] == pytest.approx(0.005 / c, rel=1e-3)
        amps.append(r["provenance"]["obliquity_amplification"])
    assert amps == sorted(amps)


def test_plane_intersect_failures(ctx):
    o = ctx.capture("head_camera")
    d = np.array(call(ctx, "ray", obs_id=o.obs_id, px=[320, 240]).payload["value"]["dir"])
    n = np.cross(d, [1, 0, 0])
    r = call(ctx, "plane_intersect", obs_id=o.obs_id, px=[320, 240], plane_point_xyz=[0, 0, 0],
             plane_normal_xyz=n.tolist(), plane_offset_sigma_m=0.01).payload
    assert r["value"] is None and r["failure"]["code"] == "RAY_PARALLEL_TO_PLANE" and not r["valid"]
    r = call(ctx, "plane_intersect", obs_id=o.obs_id, px=[320, 240], plane_point_xyz=[0, 0, 2.0],
             plane_normal_xyz=[0, 0, 1], plane_offset_sigma_m=0.01).payload
    assert r["value"] is None and r["failure"]["code"] == "BEHIND_CAMERA"


def _pair(ctx, pose_before, pose_after, valid=None):
    sim = ctx.sim
    sim.set_tcp("left", pose_before)
    ob = ctx.capture("left_camera")
    sim.set_tcp("left", pose_after)
    ctx.tick += 1
    oa = ctx.capture("left_camera")
    pid = ctx.next_pair_id()
    ctx.pairs[pid] = {"before": ob.obs_id, "after": oa.obs_id,
                      "valid": valid or {"motion_succeeded": True, "baseline_nonzero": True, "contact_free": True}}
    return pid, ob, oa


def test_triangulation_recovers_a_point_within_1mm(ctx):
    q = ctx.sim.tcp["left"][3:]
    pid, ob, oa = _pair(ctx, np.concatenate([[-0.10, -0.10, 0.95], q]), np.concatenate([[-0.02, -0.08, 1.0], q]))
    X = np.array([-0.05, 0.25, 0.93])
    pb = gt.project_points(ob.K, ob.E, X)[0][0]
    pa = gt.project_points(oa.K, oa.E, X)[0][0]
    assert all(0 <= pb[0] < 320 and 0 <= pb[1] < 240 for pb in (pb, pa))
    r = call(ctx, "triangulate_correspondence", pair_id=pid, px_before=pb.tolist(), px_after=pa.tolist()).payload
    assert r["valid"] and r["kind"] == "world_point"
    assert np.linalg.norm(np.array(r["value"]) - X) < 1e-3
    prov = r["provenance"]
    assert prov["correspondence_verified"] is False and prov["method"] == "two-ray midpoint"
    assert prov["ray_gap_m"] < 1e-6 and prov["triangulation_angle_deg"] > 5
    assert prov["depths"]["before_range_m"] > 0 and prov["depths"]["after_range_m"] > 0
    assert r["uncertainty"]["sigma_m"] > 0 and "warnings" not in prov
    # a pixel error of 3 px opens a ray gap and moves the point, within a few sigma
    r2 = call(ctx, "triangulate_correspondence", pair_id=pid, px_before=(pb + [3, 0]).tolist(),
              px_after=pa.tolist(), pixel_sigma_px=2.0).payload
    err = np.linalg.norm(np.array(r2["value"]) - X)
    assert 0 < err < 3 * r2["uncertainty"]["sigma_m"]


def test_triangulation_degenerate_and_invalid_pairs(ctx):
    q = ctx.sim.tcp["left"][3:]
    pose = np.concatenate([[-0.10, -0.10, 0.95], q])
    pid, ob, oa = _pair(ctx, pose, pose)
    r = call(ctx, "triangulate_correspondence", pair_id=pid, px_before=[160, 120], px_after=[160, 120]).payload
    assert r["value"] is None and r["failure"]["code"] == "DEGENERATE_GEOMETRY"
    pid, ob, oa = _pair(ctx, pose, np.concatenate([[-0.05, -0.10, 0.95], q]),
                        valid={"motion_succeeded": True, "baseline_nonzero": True, "contact_free": False})
    X = np.array([-0.07, 0.3, 0.9])
    r = call(ctx, "triangulate_correspondence", pair_id=pid,
             px_before=gt.project_points(ob.K, ob.E, X)[0][0].tolist(),
             px_after=gt.project_points(oa.K, oa.E, X)[0][0].tolist()).payload
    assert r["value"] is not None and not r["valid"]
    assert any("contact_free" in w for w in r["provenance"]["warnings"])
    with pytest.raises(ToolArgumentError, match="unknown pair_id"):
        call(ctx, "triangulate_correspondence", pair_id="pair_999", px_before=[1, 1], px_after=[1, 1])


@pytest.mark.parametrize("approach,opening", [([0, 0, -1], [1, 0, 0]), ([0, 1, 0], [-1, 0, 0]),
                                              ([1, 1, 0], [1, -1, 0]), ([0, 0.6, -0.8], [0, 0.8, 0.6])])
def test_grasp_quat_candidates_axes(ctx, approach, opening):
    r = call(ctx, "grasp_quat_candidates", approach_axis_world=approach, opening_axis_world=opening).payload
    a = np.array(approach, float) / np.linalg.norm(approach)
    o = np.array(opening, float) / np.linalg.norm(opening)
    qa, qb = (np.array(c["quat_wxyz"]) for c in r["candidates"])
    Ra, Rb = quat_to_mat(qa), quat_to_mat(qb)
    assert np.allclose(Ra[:, 0], a, atol=1e-6) and np.allclose(Rb[:, 0], a, atol=1e-6)
    assert np.allclose(Ra[:, 1], o, atol=1e-6) and np.allclose(Rb[:, 1], -o, atol=1e-6)
    rel = Ra.T @ Rb  # 180 deg about local x
    assert np.allclose(rel, np.diag([1, -1, -1]), atol=1e-6)
    assert r["reachability_evaluated"] is False and r["opening_axis_input_is_unoriented_line"] is True


def test_scale_from_object_size(ctx):
    o = ctx.capture("head_camera")
    f = HEAD_K[0, 0]
    # a 0.10 m wide object at 1.2 m spans f * 0.1 / 1.2 px
    w = f * 0.10 / 1.2
    r = call(ctx, "scale_from_object_size", obs_id=o.obs_id, bbox=[300, 200, 300 + w, 260], extent_axis="width",
             known_extent_m=0.10).payload
    assert r["kind"] == "depth" and r["coarse"] and r["uncertainty"] is None
    assert r["value"] == pytest.approx(1.2, rel=1e-6)
    r = call(ctx, "scale_from_object_size", obs_id=o.obs_id, bbox=[300, 200, 300 + w, 260], extent_axis="width",
             known_extent_m=0.10, known_extent_sigma_m=0.01).payload
    assert r["uncertainty"]["sigma_m"] == pytest.approx(0.12, rel=1e-6)
    h = f * 0.2 / 0.8
    r = call(ctx, "scale_from_object_size", obs_id=o.obs_id, bbox=[100, 100, 100 + h, 100 + h],
             extent_axis="diagonal", known_extent_m=0.2 * math.sqrt(2)).payload
    assert r["value"] == pytest.approx(0.8, rel=1e-6)
    # the implied point lies on the bbox-centre ray at that camera depth
    p = np.array(r["provenance"]["implied_point_at_bbox_center_world"])
    uv, z = gt.project_points(o.K, o.E, p)
    assert z[0] == pytest.approx(0.8, abs=1e-6) and np.allclose(uv[0], [100 + h / 2] * 2, atol=1e-3)


def test_draw_marks_makes_a_new_observation(ctx):
    o = ctx.capture("head_camera")
    before = o.image.copy()
    r = call(ctx, "draw_marks", obs_id=o.obs_id, pixels=[[100, 100], [630, 470], [700, 10]],
             labels=["cup", "edge", "off"])
    new = ctx.obs.get(r.obs_ids[0])
    assert new.obs_id != o.obs_id and new.source_obs_id == o.obs_id and new.tick == o.tick
    assert np.array_equal(o.image, before), "the source observation must not change"
    assert not np.array_equal(new.image, o.image)
    assert np.allclose(new.E, o.E)
    marks = r.payload["annotation"]["marks"]
    assert [mk["in_frame"] for mk in marks] == [True, True, False]
    assert [mk["color"] for mk in marks] == ["red", "green", "blue"]
    assert all(len(mk["label_bbox_px"]) == 4 for mk in marks)


def test_preview_requires_a_current_observation_and_reports_geometry(ctx):
    o = ctx.capture("head_camera")
    tcp = [0.0, 0.1, 0.85]
    q = [0.7071068, 0, 0.7071068, 0]  # approach -z (top-down)
    r = call(ctx, "preview_tcp_pose", obs_id=o.obs_id, arm="left", tcp_xyz=tcp, quat_wxyz=q,
             reference_xyz_world=[0.0, 0.1, 0.80])
    ann = r.payload["annotation"]
    assert r.payload["source_obs_id"] == o.obs_id
    assert ann["finger_gap_source"] == "live_fk" and ann["finger_gap_m"] == pytest.approx(0.088)
    assert ann["in_view"]["grasp_center"] and ann["in_view"]["all_fingers"]
    assert np.allclose(ann["grasp_center"]["px"], gt.project_points(o.K, o.E, np.array(tcp))[0][0], atol=0.01)
    assert "approach points down (-z)" in ann["orientation"]["reads_as"]["approach"]
    assert ann["reference"]["delta_gripper_m"]["approach"] == pytest.approx(0.05, abs=1e-6)
    tips = [np.array(t["xyz"]) for t in ann["inner_tips"]]
    assert np.linalg.norm(tips[0] - tips[1]) == pytest.approx(0.088 - 2 * 0.010, abs=1e-6)
    assert not np.array_equal(ctx.obs.get(r.obs_ids[0]).image, o.image)
    ctx.tick += 1
    with pytest.raises(ToolArgumentError, match="capture a fresh observation"):
        call(ctx, "preview_tcp_pose", obs_id=o.obs_id, arm="left", tcp_xyz=tcp, quat_wxyz=q)


def test_compare_tcp_poses_pairs(ctx):
    o = ctx.capture("head_camera")
    down = [0.7071068, 0, 0.7071068, 0]
    cands = [{"arm": "left", "tcp_xyz": [-0.05, 0.1, 0.85], "quat_wxyz": down},
             {"arm": "right", "tcp_xyz": [0.05, 0.1, 0.85], "quat_wxyz": down, "finger_gap_m": 0.06},
             {"arm": "left", "tcp_xyz": [-0.05, 0.1, 0.95], "quat_wxyz": approach_y_quat().tolist()}]
    r = call(ctx, "compare_tcp_poses", obs_id=o.obs_id, candidates=cands).payload["annotation"]
    assert [c["index"] for c in r["candidates"]] == [1, 2, 3]
    pairs = {tuple(p["pair"]): p for p in r["pairs"]}
    assert set(pairs) == {(1, 2), (1, 3), (2, 3)}
    p12 = pairs[(1, 2)]
    assert p12["grasp_center_distance_m"] == pytest.approx(0.10) and p12["approach_angle_deg"] == pytest.approx(0, abs=1e-3)
    assert p12["finger_separation_m"] is not None and p12["finger_bbox_overlap"] is False
    p13 = pairs[(1, 3)]
    assert p13["same_arm"] and p13["finger_separation_m"] is None and p13["approach_angle_deg"] == pytest.approx(90, abs=1e-3)
    assert p13["nearer_to_camera"] in (1, 3)


def test_scale_from_gripper_measures_the_fingertips(ctx):
    r = call(ctx, "scale_from_gripper", camera="head_camera", arm="right")  # start pose: outside the head view
    ann = r.payload["annotation"]
    assert ann["failure_reason"] == "endpoint_out_of_frame" and not ann["valid_metric_reference"]
    ctx.sim.set_tcp("right", np.concatenate([[0.10, 0.05, 0.85], approach_y_quat()]))
    r = call(ctx, "scale_from_gripper", camera="head_camera", arm="right")
    ann = r.payload["annotation"]
    assert ann["true_dist_m"] == pytest.approx(0.088 - 2 * 0.010, abs=1e-6)
    assert all(ann["endpoint_in_frame"]) and ann["valid_metric_reference"] and ann["failure_reason"] is None
    assert ann["meters_per_pixel_along_segment"] == pytest.approx(ann["true_dist_m"] / ann["span_px"], rel=1e-4)
    assert r.payload["camera"] == "head_camera" and r.payload["tick"] == ctx.tick


def test_camera_aim_pose_centres_the_target(ctx):
    target = [0.05, 0.15, TABLE_Z]
    r = call(ctx, "camera_aim_pose", camera="left_camera", target_xyz=target, pitch=90, standoff=0.28).payload
    assert r["valid"] and r["arm"] == "left" and r["reason"] is None
    pose = np.array(r["target_tcp_pose_world"])
    assert pose[2] == pytest.approx(TABLE_Z + 0.28, abs=1e-6)
    assert np.allclose(quat_to_mat(pose[3:])[:, 0], [0, 0, -1], atol=1e-6)
    # independently: put the TCP there; the fake sim's camera then sees the target at the image centre
    ctx.sim.set_tcp("left", pose)
    E = ctx.camera_E("left_camera")
    uv, z = gt.project_points(WRIST_K, E, np.array(target))
    assert np.allclose(uv[0], [160, 120], atol=1e-3) and z[0] > 0.1
    assert r["predicted_projection"]["depth_m"] == pytest.approx(z[0], abs=1e-5)
    # a tilted pitch still centres it
    ctx.sim.set_tcp("left", np.concatenate([[-0.30, -0.19, 0.94], approach_y_quat()]))
    r = call(ctx, "camera_aim_pose", camera="left_camera", target_xyz=target, pitch=70).payload
    ctx.sim.set_tcp("left", r["target_tcp_pose_world"])
    uv, _ = gt.project_points(WRIST_K, ctx.camera_E("left_camera"), np.array(target))
    assert np.allclose(uv[0], [160, 120], atol=1e-3)


# ==============================================================================================
# observation / feedback handlers
# ==============================================================================================
def test_grasp_contact_is_anonymous(ctx):
    ctx.sim.contacts = [Contact("robot/fl_link7", "apple", 0.02, (0.0, 0.1, 0.8)),
                        Contact("tray", "robot/fl_link8", 0.00005, None),  # below threshold
                        Contact("robot/fl_link7", "robot/fl_link8", 0.5, None),  # finger-finger
                        Contact("robot/fr_link7", "apple", 0.3, None)]  # the other arm
    p = call(ctx, "get_grasp_contact", arm="left").payload
    text = json.dumps(p)
    assert "apple" not in text and "tray" not in text
    assert p["fingers_in_contact"] == ["fl_link7"]
    assert p["total_impulse"] == pytest.approx(0.02)
    assert set(p["contacting_finger_pose"]) == {"fl_link7"}
    assert p["contact_localization"]["per_finger"]["fl_link7"]["point_world"] == [0.0, 0.1, 0.8]
    s = call(ctx, "get_robot_state", arms=["left"]).payload
    assert s["arms"]["left"]["contact"]["fingers_in_contact"] == ["fl_link7"]
    assert "apple" not in json.dumps(s)


def test_arm_gripper_and_robot_state(ctx):
    p = call(ctx, "get_arm_pose", arm="left").payload
    assert p["tcp_pose"][:3] == [-0.3, -0.19, 0.94]
    assert "forward (+y)" in p["orientation"]["reads_as"]["approach"]
    assert np.allclose(p["orientation"]["approach_axis_world"], [0, 1, 0])
    ctx.gripper_cmd["left"] = 0.1
    g = call(ctx, "get_gripper_state", arm="left").payload
    assert g["opening_m"] == pytest.approx(0.008) and g["finger_gap_m"] == pytest.approx(0.088)
    assert g["drive_commanded_closed"] is True and g["gripper_val"] == 0.1
    s = call(ctx, "get_robot_state").payload
    js = s["arms"]["right"]["joint_state"]
    assert js["names"][-2:] == ["fr_joint7", "fr_joint8"] and js["positions"][-2:] == [0.02, 0.02]
    assert js["types"].count("revolute") == 6 and set(s["arms"]) == {"left", "right"}


def test_captures_and_world_frame(ctx):
    w = call(ctx, "get_world_frame")
    assert w.payload["annotation"]["legend"]["display_only"] is True and len(w.obs_ids) == 1
    raw = ctx.sim.render("head_camera")
    assert not np.array_equal(ctx.obs.get(w.obs_ids[0]).image, raw)
    h = call(ctx, "capture_head")
    assert h.payload["cam_pose_snapshot"]["size_hw"] == [480, 640]
    s = call(ctx, "capture_wrist", active_arm="right", views="both")
    assert list(s.payload["roles"]) == ["active", "opposite"]
    assert [o["camera"] for o in s.payload["observations"]] == ["right_camera", "left_camera"]
    s = call(ctx, "capture_wrist", active_arm="none", views="both")
    assert len(s.obs_ids) == 2
    e = call(ctx, "capture_evidence_views", active_arm="left")
    assert [o["camera"] for o in e.payload["observations"]] == ["head_camera", "left_camera", "right_camera"]
    assert e.payload["roles"]["active"] == e.payload["roles"]["left_wrist"]
    assert len({o["tick"] for o in e.payload["observations"]}) == 1
    ci = call(ctx, "get_camera_info", camera="head_camera").payload
    assert ci["available"] and np.allclose(ci["E"], HEAD_E) and ci["size_hw"] == [480, 640]


def test_embodiment_card_has_no_scene_facts(ctx):
    card = call(ctx, "get_embodiment").payload
    assert card["motion"]["max_single_displacement_m"] == 0.30 and card["motion"]["contact_leg_m"] == 0.03
    assert card["arms"]["left"]["side"].startswith("-x")
    assert card["gripper"]["max_opening_m"] == 0.08
    json.dumps(card)


def test_payloads_are_json(ctx):
    o = ctx.capture("head_camera")
    for name, kw in [("project", {"obs_id": o.obs_id, "xyz": [0, 0, 0.74]}),
                     ("plane_intersect", {"obs_id": o.obs_id, "px": [320, 300], "plane_point_xyz": [0, 0, 0.74],
                                          "plane_normal_xyz": [0, 0, 1], "plane_offset_sigma_m": 0.002}),
                     ("camera_aim_pose", {"camera": "right_camera", "target_xyz": [0.1, 0.1, 0.75]})]:
        json.dumps(call(ctx, name, **kw).payload, allow_nan=False)


def test_declared_embodiment_facts_refine_card_and_finger_geometry(ctx):
    emb_mod = pytest.importorskip("cab_embodiment_aloha.embodiment")
    params = pytest.importorskip("cab_embodiment_aloha.params")
    import dataclasses

    facts = emb_mod.facts(params.DEFAULT_PARAMS)
    ctx.emb = dataclasses.replace(ctx.emb, facts=facts)
    card = call(ctx, "get_embodiment").payload
    assert card["embodiment"] == "aloha_agilex" and isinstance(card["reachability"], dict)
    assert card["reachability"]["description"].startswith("each arm reaches")
    assert card["motion"]["max_single_displacement_m"] == 0.30
    inner = facts["gripper"]["finger_origin_to_inner_pad_face_m"]
    ctx.sim.set_tcp("right", np.concatenate([[0.10, 0.05, 0.85], approach_y_quat()]))
    ann = call(ctx, "scale_from_gripper", camera="head_camera", arm="right").payload["annotation"]
    assert ann["true_dist_m"] == pytest.approx(0.088 - 2 * inner, abs=1e-6)  # the pads' clearance
