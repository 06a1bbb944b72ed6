"""The scene in the Rerun export (issue 30, item 5): a real attempt (click_bell, its oracle, on MuJoCo,
with distractors so that the scene has bodies that move), exported and read back with
``rerun.dataframe`` and ``rerun rrd print``. Expected values come from the record
(``privileged/scene_info.json``, ``privileged/snapshots.jsonl``), not from the converter."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from cab_core.geometry import quat_to_mat  # noqa: E402
from cab_export_rerun.convert import convert  # noqa: E402
from cab_export_rerun.scene import urdf_links  # noqa: E402

SHAPE = re.compile(r"/world/objects/([^/]+)/shape_(\d+)")


@pytest.fixture(scope="module")
def attempt(tmp_path_factory) -> Path:
    from attempt_records import run_one

    d = tmp_path_factory.mktemp("rerun_scene") / "attempt"
    run_one(d, "click_bell", "oracle", 1, "sim=mujoco", "randomize=distractors")
    convert(d, d / "attempt.rrd", video=False)
    return d


def _jsonl(p: Path) -> list[dict]:
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def _static(rec, entity: str, components: list[str]) -> dict[str, object]:
    table = rec.view(index="snapshot", contents={entity: components}).select_static().read_all()
    return {c.split(":", 1)[1]: table.column(c).to_pylist()[0] for c in table.column_names}


def _components(rec) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for c in rec.schema().component_columns():
        out.setdefault(c.entity_path, set()).add(c.component_name.rsplit(".", 1)[-1])
    return out


def _points(rec, entity: str, components: set[str]) -> tuple[str, np.ndarray]:
    """``(kind, points)``: the shape's archetype (its indicator), and points spanning it in its body's
    frame (a box's corners, an ellipsoid's axis ends, a mesh's vertices), through the shape's static
    transform."""
    s = _static(rec, entity, ["HalfSize3D", "Position3D", "TriangleIndices", "Translation3D", "RotationQuat"])
    if "Mesh3DIndicator" in components:
        kind, local = "mesh", np.asarray(s["Position3D"], float)
        assert len(s["TriangleIndices"]) > 0
    elif {"Boxes3DIndicator", "Ellipsoids3DIndicator"} & components:
        h = np.asarray(s["HalfSize3D"][0], float)
        kind = "box" if "Boxes3DIndicator" in components else "ellipsoid"
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        local = signs * h if kind == "box" else np.vstack([np.diag(h), -np.diag(h)])
    else:
        raise AssertionError(f"{entity} holds no geometry: {sorted(s)}")
    x, y, z, w = s["RotationQuat"][0]
    return kind, local @ quat_to_mat([w, x, y, z]).T + np.asarray(s["Translation3D"][0], float)


def _world(pose, pts: np.ndarray) -> np.ndarray:
    return pts @ quat_to_mat(pose[3:7]).T + np.asarray(pose[:3], float)


@pytest.mark.sim
def test_every_scene_body_has_geometry_of_its_size(attempt):
    info = json.loads((attempt / "privileged" / "scene_info.json").read_text())
    first = _jsonl(attempt / "privileged" / "snapshots.jsonl")[0]["objects"]
    rec = rr.dataframe.load_recording(str(attempt / "attempt.rrd"))
    shapes: dict[str, list[str]] = {}
    for c in rec.schema().component_columns():
        if (m := SHAPE.fullmatch(c.entity_path)) and c.entity_path not in shapes.get(m[1], []):
            shapes.setdefault(m[1], []).append(c.entity_path)
    assert sorted(shapes) == sorted(info["objects"]) == sorted(first)  # table, wall, bell, the distractors
    comps = _components(rec)
    body = {n: [_points(rec, e, comps[e]) for e in sorted(es)] for n, es in shapes.items()}

    top = info["info"]["table_top_z"]  # the table's highest shape is its top, at the recorded height
    table_z = max(_world(first["table"]["pose"], p)[:, 2].max() for _, p in body["table"])
    assert table_z == pytest.approx(top, abs=1e-6)
    assert {k for k, _ in body["table"]} == {"box"} and len(body["table"]) == 5  # the top and four legs

    bell = info["info"]["bell"]  # the bell: cylinders and its dome (meshes), from the table to its knob
    pts = np.vstack([p for _, p in body["bell"]])
    assert {k for k, _ in body["bell"]} == {"mesh"}
    assert pts[:, 2].min() == pytest.approx(0.0, abs=1e-6) and pts[:, 2].max() == pytest.approx(bell["height"], abs=1e-3)
    assert np.hypot(pts[:, 0], pts[:, 1]).max() == pytest.approx(bell["radius"], abs=1e-6)

    placed = info["randomization"]["distractors"]["placed"]
    assert placed
    for d in placed:  # a distractor of its drawn shape and size
        [(kind, p)] = body[d["name"]]
        size = d["size_m"]
        assert kind == {"box": "box", "sphere": "ellipsoid", "cylinder": "mesh"}[d["shape"]]
        ext = p.max(axis=0) - p.min(axis=0)
        if d["shape"] == "cylinder":  # along x, its length and diameter both 2 x size
            assert ext == pytest.approx([2 * size] * 3, abs=1e-5)
            assert np.hypot(p[:, 1], p[:, 2]).max() == pytest.approx(size, abs=1e-6)
        else:
            assert ext == pytest.approx([2 * size] * 3, abs=1e-6)


@pytest.mark.sim
def test_a_moved_body_is_posed_by_its_recorded_transforms(attempt):
    snaps = _jsonl(attempt / "privileged" / "snapshots.jsonl")
    moved = {n: np.linalg.norm(np.subtract(snaps[-1]["objects"][n]["pose"][:3], snaps[0]["objects"][n]["pose"][:3]))
             for n in snaps[0]["objects"]}
    name = max(moved, key=moved.__getitem__)
    assert moved[name] > 1e-4 and name.startswith("distractor_")  # a distractor rolled as the scene settled
    rec = rr.dataframe.load_recording(str(attempt / "attempt.rrd"))
    entity = f"/world/objects/{name}"
    table = rec.view(index="snapshot", contents={entity: ["Translation3D", "RotationQuat"]}).select().read_all()
    xyz = [v[0] for v in table.column(f"{entity}:Translation3D").to_pylist()]
    quat = [v[0] for v in table.column(f"{entity}:RotationQuat").to_pylist()]
    assert len(xyz) == len(snaps)
    assert np.allclose(xyz, [s["objects"][name]["pose"][:3] for s in snaps], atol=1e-6)
    w = [s["objects"][name]["pose"][3:7] for s in snaps]
    assert np.allclose(quat, [[q[1], q[2], q[3], q[0]] for q in w], atol=1e-6)
    assert not np.allclose(xyz[0], xyz[-1], atol=1e-5)
    # its geometry is one static shape under it: the 3D view draws it wherever the transform puts it
    cols = [c for c in rec.schema().component_columns() if c.entity_path == f"{entity}/shape_0"]
    assert cols and all(c.is_static for c in cols)


@pytest.mark.sim
def test_rrd_print_lists_the_shapes(attempt):
    cli = Path(sys.executable).parent / "rerun"
    if not cli.exists():
        pytest.skip("the rerun command line is not installed beside this Python")
    out = subprocess.run([str(cli), "rrd", "print", str(attempt / "attempt.rrd")], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    kinds: dict[str, set[str]] = {}
    for entity, cols in re.findall(r" - (/world/objects/[^ ]+/shape_\d+) - columns: \[([^\]]*)\]", out.stdout):
        kinds.setdefault(entity, set()).update(c for c in cols.split() if c.endswith("Indicator"))
    assert kinds["/world/objects/wall/shape_0"] == {"Boxes3DIndicator", "Transform3DIndicator"}
    assert kinds["/world/objects/bell/shape_2"] == {"Mesh3DIndicator", "Transform3DIndicator"}  # the dome (OBJ)


@pytest.mark.sim
@pytest.mark.parametrize("file, change, says", [
    ("privileged/scene_info.json", {"task": "no_such_task"}, "unknown task 'no_such_task'; choices: "),
    ("result.json", {"embodiment": None}, "the record does not name its task, seed and embodiment"),
])
def test_a_scene_that_cannot_be_rebuilt_is_one_error_line(attempt, tmp_path, file, change, says):
    d = tmp_path / "attempt"
    shutil.copytree(attempt, d, ignore=shutil.ignore_patterns("*.rrd", "*.mp4", "observations"))
    (d / file).write_text(json.dumps({**json.loads((d / file).read_text()), **change}))
    rec = rr.dataframe.load_recording(str(convert(d, video=False)))
    assert not any(SHAPE.fullmatch(c.entity_path) for c in rec.schema().component_columns())
    assert "/world/objects/bell" in {c.entity_path for c in rec.schema().component_columns()}  # the rest is there
    [[line]] = rec.view(index="snapshot", contents={"/log/scene": ["Text"]}).select_static().read_all() \
        .column("/log/scene:Text").to_pylist()
    assert line.startswith(f"the scene's geometry is not drawn: {says}") and "\n" not in line


@pytest.mark.sim
def test_an_articulated_object_is_drawn_link_by_link(tmp_path):
    """open_microwave ended at once (a scripted ``done``): each link of the microwave's URDF has its
    visuals under the link's recorded pose."""
    import xml.etree.ElementTree as ET

    from attempt_records import run_one

    from cab_core.kits.registry import task_instance

    script = tmp_path / "script.json"
    script.write_text(json.dumps([{"tool": "done", "args": {"report": "nothing done", "success_claim": False}}]))
    d = tmp_path / "attempt"
    run_one(d, "open_microwave", "scripted", 1, "sim=mujoco", f"model.script={script}")
    rec = rr.dataframe.load_recording(str(convert(d, video=False)))
    comps = _components(rec)
    [art] = task_instance("open_microwave", 0, "aloha_agilex").scene.articulations
    visuals = {link.get("name"): len(link.findall("visual")) for link in ET.parse(art.urdf).getroot().findall("link")}
    recorded = _jsonl(d / "privileged" / "snapshots.jsonl")[0]["objects"][art.name]["links"]
    assert set(visuals) == set(recorded) == {"base", "door"}
    for link, n in visuals.items():
        entity = f"/world/object_links/{art.name}/{link}"
        drawn = sorted(e for e in comps if e.startswith(entity + "/visual_"))
        assert len(drawn) == n > 0
        assert all({"Boxes3DIndicator", "Mesh3DIndicator"} & comps[e] for e in drawn)  # boxes; cylinders as meshes
        assert len(rec.view(index="snapshot", contents={entity: ["Translation3D"]}).select().read_all()) == \
            len(_jsonl(d / "privileged" / "snapshots.jsonl"))


URDF = """<robot name="lamp">
  <material name="brass"><color rgba="0.8 0.6 0.2 1"/></material>
  <link name="foot">
    <visual><origin xyz="0 0 0.01" rpy="0 0 0"/><geometry><cylinder radius="0.05" length="0.02"/></geometry>
      <material name="brass"/></visual>
    <collision><geometry><box size="1 1 1"/></geometry></collision>
  </link>
  <link name="arm">
    <visual><origin xyz="0.1 0 0" rpy="0 1.5707963267948966 0"/><geometry><box size="0.2 0.02 0.04"/></geometry>
      <material name="red"><color rgba="1 0 0 1"/></material></visual>
    <visual><geometry><mesh filename="shade.obj" scale="2 2 2"/></geometry></visual>
    <visual><geometry><sphere radius="0.01"/></geometry></visual>
  </link>
  <joint name="hinge" type="revolute"><parent link="foot"/><child link="arm"/></joint>
</robot>"""


def test_urdf_visuals_are_read_with_their_poses_sizes_and_colours(tmp_path):
    (tmp_path / "lamp.urdf").write_text(URDF)
    root, links = urdf_links(str(tmp_path / "lamp.urdf"))
    assert root == "foot" and list(links) == ["foot", "arm"]
    [foot] = links["foot"]  # the collision box is not drawn
    assert (foot.kind, foot.size, foot.axis, foot.rgba) == ("cylinder", (0.05, 0.01), "z", (0.8, 0.6, 0.2, 1.0))
    assert foot.pose == (0.0, 0.0, 0.01, 1.0, 0.0, 0.0, 0.0)
    box, mesh, ball = links["arm"]
    assert (box.kind, box.size, box.rgba) == ("box", (0.1, 0.01, 0.02), (1.0, 0.0, 0.0, 1.0))
    assert box.pose[:3] == (0.1, 0.0, 0.0)
    assert np.allclose(box.pose[3:], [np.cos(np.pi / 4), 0.0, np.sin(np.pi / 4), 0.0])  # 90 degrees about y
    assert (mesh.kind, mesh.size, mesh.mesh) == ("mesh", (2.0, 2.0, 2.0), str(tmp_path / "shade.obj"))
    assert (ball.kind, ball.size) == ("sphere", (0.01,))
