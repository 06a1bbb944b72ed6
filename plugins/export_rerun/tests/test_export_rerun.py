"""The scene in the Rerun export (issue 30, item 5): a real attempt (click_bell, its oracle, on MuJoCo,
with distractors so that the scene has bodies that move), exported and read back with rerun-sdk's
reader (:class:`cab_export_rerun.readback.Recording`, on ``rerun.chunk.RrdReader``) and with the
command line ``rerun rrd print``. Expected values come from the record (``privileged/scene_info.json``,
``privileged/snapshots.jsonl``), not from the converter."""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun")

from cab_core.geometry import quat_to_mat  # noqa: E402
from cab_export_rerun.convert import convert  # noqa: E402
from cab_export_rerun.readback import Recording  # noqa: E402
from cab_export_rerun.scene import urdf_links  # noqa: E402

SHAPE = re.compile(r"/world/objects/([^/]+)/shape_(\d+)")
GEOMETRY = {"Boxes3D", "Ellipsoids3D", "Capsules3D", "Cylinders3D", "Mesh3D"}
RIM = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)  # a cylinder's rims sampled, 0, 90, 180, 270 degrees among them


@pytest.fixture(scope="module")
def attempt(tmp_path_factory) -> Path:
    from attempt_records import run_one

    d = tmp_path_factory.mktemp("rerun_scene") / "attempt"
    run_one(d, "click_bell", "oracle", 1, "sim=mujoco", "randomize=distractors")
    convert(d, d / "attempt.rrd", video=False)
    return d


def _jsonl(p: Path) -> list[dict]:
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]


def _xyzw_mat(q) -> np.ndarray:
    x, y, z, w = q
    return quat_to_mat([w, x, y, z])


def _points(rec: Recording, entity: str) -> tuple[str, np.ndarray]:
    """``(archetype, points)``: the shape's geometry, and points spanning it in its body's frame (a
    box's corners, an ellipsoid's axis ends, a cylinder's rims, a mesh's vertices), through the
    shape's static transform."""
    [kind] = rec.archetypes(entity) & GEOMETRY
    assert all(rec.is_static(entity, c) for c in rec.components(entity))
    if kind == "Mesh3D":
        local = np.asarray(rec.static(entity, "Mesh3D:vertex_positions"), float)
        assert len(rec.static(entity, "Mesh3D:triangle_indices")) > 0
    elif kind in ("Boxes3D", "Ellipsoids3D"):
        [h] = np.asarray(rec.static(entity, f"{kind}:half_sizes"), float)
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        local = signs * h if kind == "Boxes3D" else np.vstack([np.diag(h), -np.diag(h)])
    elif kind == "Cylinders3D":  # along its own z, centred, then turned by its quaternion
        [length], [r] = rec.static(entity, "Cylinders3D:lengths"), rec.static(entity, "Cylinders3D:radii")
        rim = np.stack([r * np.cos(RIM), r * np.sin(RIM), np.zeros_like(RIM)], axis=1)
        local = np.vstack([rim + [0.0, 0.0, -length / 2], rim + [0.0, 0.0, length / 2]])
        [q] = rec.static(entity, "Cylinders3D:quaternions") or [[0.0, 0.0, 0.0, 1.0]]
        local = local @ _xyzw_mat(q).T
    else:
        raise AssertionError(f"{entity}: no points for {kind}")
    [t], [q] = rec.static(entity, "Transform3D:translation"), rec.static(entity, "Transform3D:quaternion")
    return kind, local @ _xyzw_mat(q).T + np.asarray(t, float)


def _world(pose, pts: np.ndarray) -> np.ndarray:
    return pts @ quat_to_mat(pose[3:7]).T + np.asarray(pose[:3], float)


def _shapes(entities) -> dict[str, list[str]]:
    out: dict[str, list[str]] = defaultdict(list)
    for e in sorted(entities, key=lambda e: [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", e)]):
        if m := SHAPE.fullmatch(e):
            out[m[1]].append(e)
    return dict(out)


@pytest.mark.sim
def test_every_scene_body_has_geometry_of_its_size(attempt):
    info = json.loads((attempt / "privileged" / "scene_info.json").read_text())
    first = _jsonl(attempt / "privileged" / "snapshots.jsonl")[0]["objects"]
    rec = Recording(attempt / "attempt.rrd")
    shapes = _shapes(rec.entities)
    assert sorted(shapes) == sorted(info["objects"]) == sorted(first)  # table, wall, bell, the distractors
    body = {n: [_points(rec, e) for e in es] for n, es in shapes.items()}

    top = info["info"]["table_top_z"]  # the table's highest shape is its top, at the recorded height
    table_z = max(_world(first["table"]["pose"], p)[:, 2].max() for _, p in body["table"])
    assert table_z == pytest.approx(top, abs=1e-6)
    assert [k for k, _ in body["table"]] == ["Boxes3D"] * 5  # the top and four legs
    assert [k for k, _ in body["wall"]] == ["Boxes3D"]

    bell = info["info"]["bell"]  # the bell: cylinders (base, stem, knob) and its dome (a mesh), table to knob
    assert sorted(k for k, _ in body["bell"]) == ["Cylinders3D"] * 4 + ["Mesh3D"]
    pts = np.vstack([p for _, p in body["bell"]])
    assert pts[:, 2].min() == pytest.approx(0.0, abs=1e-6) and pts[:, 2].max() == pytest.approx(bell["height"], abs=1e-3)
    assert np.hypot(pts[:, 0], pts[:, 1]).max() == pytest.approx(bell["radius"], abs=1e-6)

    placed = info["randomization"]["distractors"]["placed"]
    assert placed
    for d in placed:  # a distractor of its drawn shape and size
        [(kind, p)] = body[d["name"]]
        size = d["size_m"]
        assert kind == {"box": "Boxes3D", "sphere": "Ellipsoids3D", "cylinder": "Cylinders3D"}[d["shape"]]
        assert p.max(axis=0) - p.min(axis=0) == pytest.approx([2 * size] * 3, abs=1e-6)
        if d["shape"] == "cylinder":  # along x: its rims are circles of radius size about the x axis
            assert np.hypot(p[:, 1], p[:, 2]) == pytest.approx(np.full(len(p), size), abs=1e-6)


@pytest.mark.sim
def test_the_attempt_s_frames_are_its_recorded_poses(attempt):
    """Every object, and each arm's TCP, has one transform per snapshot (its recorded pose) and axes
    drawn at it; the body with the largest motion moves in the recording as in the record."""
    snaps = _jsonl(attempt / "privileged" / "snapshots.jsonl")
    rec = Recording(attempt / "attempt.rrd")
    frames = {f"/world/objects/{n}": [s["objects"][n]["pose"] for s in snaps] for n in snaps[0]["objects"]}
    frames |= {f"/world/robot/{a}/tcp": [s["arms"][a]["tcp_pose"] for s in snaps] for a in snaps[0]["arms"]}
    assert len(frames) == len(snaps[0]["objects"]) + 2
    for entity, poses in frames.items():
        xyz = [v for [v] in rec.rows(entity, "Transform3D:translation", "snapshot")]
        quat = [v for [v] in rec.rows(entity, "Transform3D:quaternion", "snapshot")]
        assert np.allclose(xyz, [p[:3] for p in poses], atol=1e-6), entity
        assert np.allclose(quat, [[p[4], p[5], p[6], p[3]] for p in poses], atol=1e-6), entity
        axes = rec.rows(entity, "TransformAxes3D:axis_length", "snapshot")
        assert axes == [[pytest.approx(0.1 if "/tcp" in entity else 0.05)]] * len(snaps), entity
    # on sim_time: each snapshot at its physics step x the timestep
    dt = json.loads((attempt / "result.json").read_text())["budget"]["sim_dt"]
    times = [t.total_seconds() for t in rec.times("/world/objects/bell", "Transform3D:translation", "sim_time")]
    assert times == pytest.approx([s["physics_step"] * dt for s in snaps], abs=1e-9)

    moved = {n: np.linalg.norm(np.subtract(snaps[-1]["objects"][n]["pose"][:3], snaps[0]["objects"][n]["pose"][:3]))
             for n in snaps[0]["objects"]}
    name = max(moved, key=moved.__getitem__)
    assert moved[name] > 1e-4 and name.startswith("distractor_")  # a distractor rolled as the scene settled
    xyz = [v for [v] in rec.rows(f"/world/objects/{name}", "Transform3D:translation", "snapshot")]
    assert not np.allclose(xyz[0], xyz[-1], atol=1e-5)
    # its geometry is static, under it: the 3D view draws it wherever the transform puts it
    assert all(rec.is_static(f"/world/objects/{name}/shape_0", c) for c in rec.components(f"/world/objects/{name}/shape_0"))


def _rrd_print(path: Path) -> dict[str, dict]:
    """``rerun rrd print``'s chunk lines, by entity: its columns and its rows (temporal chunks)."""
    cli = Path(sys.executable).parent / "rerun"
    if not cli.exists():
        pytest.skip("the rerun command line is not installed beside this Python")
    out = subprocess.run([str(cli), "rrd", "print", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = re.findall(r"^Chunk\(\w+\) with (\d+) rows \([^)]*\) - (/\S*) - data columns: \[([^\]]*)\]$",
                       out.stdout, re.M)
    assert lines, out.stdout[:2000]
    entities: dict[str, dict] = defaultdict(lambda: {"columns": set(), "chunks": []})
    for rows, entity, cols in lines:
        entities[entity]["columns"].update(cols.split())
        entities[entity]["chunks"].append((int(rows), set(cols.split())))
    return dict(entities)


@pytest.mark.sim
def test_rrd_print_lists_every_body_s_geometry_and_frames(attempt):
    info = json.loads((attempt / "privileged" / "scene_info.json").read_text())
    snaps = _jsonl(attempt / "privileged" / "snapshots.jsonl")
    printed = _rrd_print(attempt / "attempt.rrd")
    shapes = _shapes(printed)
    assert sorted(shapes) == sorted(info["objects"])
    for e in [e for es in shapes.values() for e in es]:  # each shape: its local pose and one geometry archetype
        archetypes = {c.split(":", 1)[0] for c in printed[e]["columns"]}
        assert len(archetypes & GEOMETRY) == 1 and "Transform3D" in archetypes, (e, archetypes)
    assert {"Boxes3D:half_sizes", "Boxes3D:fill_mode"} <= printed["/world/objects/wall/shape_0"]["columns"]
    assert {"Mesh3D:vertex_positions", "Mesh3D:triangle_indices"} <= printed["/world/objects/bell/shape_2"]["columns"]  # the dome (OBJ)
    assert {"Cylinders3D:lengths", "Cylinders3D:radii"} <= printed["/world/objects/bell/shape_0"]["columns"]
    for d in info["randomization"]["distractors"]["placed"]:
        kind = {"box": "Boxes3D", "sphere": "Ellipsoids3D", "cylinder": "Cylinders3D"}[d["shape"]]
        assert any(c.startswith(kind + ":") for c in printed[f"/world/objects/{d['name']}/shape_0"]["columns"])
    # the frames: a transform and axes per snapshot on every object and TCP
    for entity in [f"/world/objects/{n}" for n in info["objects"]] + [f"/world/robot/{a}/tcp" for a in snaps[0]["arms"]]:
        assert {"Transform3D:translation", "Transform3D:quaternion", "TransformAxes3D:axis_length"} <= \
            printed[entity]["columns"], entity
        assert sum(n for n, cols in printed[entity]["chunks"] if "Transform3D:translation" in cols) == len(snaps)


@pytest.mark.sim
@pytest.mark.parametrize("file, change, says", [
    ("privileged/scene_info.json", {"task": "no_such_task"}, "unknown task 'no_such_task'; choices: "),
    ("result.json", {"embodiment": None}, "the record does not name its task, seed and embodiment"),
])
def test_a_scene_that_cannot_be_rebuilt_is_one_error_line(attempt, tmp_path, file, change, says):
    d = tmp_path / "attempt"
    shutil.copytree(attempt, d, ignore=shutil.ignore_patterns("*.rrd", "*.mp4", "observations"))
    (d / file).write_text(json.dumps({**json.loads((d / file).read_text()), **change}))
    rec = Recording(convert(d, video=False))
    assert not any(SHAPE.fullmatch(e) for e in rec.entities)
    assert "/world/objects/bell" in rec.entities  # the rest is there
    [line] = rec.static("/log/scene", "TextLog:text")
    assert rec.static("/log/scene", "TextLog:level") == ["ERROR"]
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
    rec = Recording(convert(d, video=False))
    [art] = task_instance("open_microwave", 0, "aloha_agilex").scene.articulations
    visuals = {link.get("name"): len(link.findall("visual")) for link in ET.parse(art.urdf).getroot().findall("link")}
    recorded = _jsonl(d / "privileged" / "snapshots.jsonl")[0]["objects"][art.name]["links"]
    assert set(visuals) == set(recorded) == {"base", "door"}
    for link, n in visuals.items():
        entity = f"/world/object_links/{art.name}/{link}"
        drawn = sorted(e for e in rec.entities if e.startswith(entity + "/visual_"))
        assert len(drawn) == n > 0
        assert all(len(rec.archetypes(e) & GEOMETRY) == 1 for e in drawn)
        assert len(rec.rows(entity, "Transform3D:translation", "snapshot")) == \
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


def test_readback_orders_rows_by_their_timeline_and_keeps_static_values_apart(tmp_path):
    path = tmp_path / "r.rrd"
    rec = rr.RecordingStream("cab", recording_id="readback", send_properties=False)
    rec.save(path)
    rec.log("thing/shape", rr.Boxes3D(half_sizes=[[0.1, 0.2, 0.3]]), static=True)
    for seq, x in ((2, 0.2), (0, 0.0), (1, 0.1)):  # logged out of order
        rec.set_time("snapshot", sequence=seq)
        rec.set_time("sim_time", duration=seq * 0.5)
        rec.log("thing", rr.Transform3D(translation=[x, 0.0, 0.0]))
    rec.flush()
    rec.disconnect()
    r = Recording(path)
    assert (r.application_id, r.recording_id) == ("cab", "readback")
    assert r.entities == {"/thing", "/thing/shape"}
    assert r.archetypes("/thing/shape") == {"Boxes3D"} and r.is_static("/thing/shape", "Boxes3D:half_sizes")
    assert r.static("/thing/shape", "Boxes3D:half_sizes") == [pytest.approx([0.1, 0.2, 0.3])]
    assert not r.is_static("/thing", "Transform3D:translation") and r.static("/thing", "Transform3D:translation") is None
    assert [v[0][0] for v in r.rows("/thing", "Transform3D:translation", "snapshot")] == pytest.approx([0.0, 0.1, 0.2])
    assert r.times("/thing", "Transform3D:translation", "snapshot") == [0, 1, 2]
    assert [t.total_seconds() for t in r.times("/thing", "Transform3D:translation", "sim_time")] == [0.0, 0.5, 1.0]
    assert r.rows("/thing", "Transform3D:translation", "event") == []  # a timeline it was not logged on


def test_readback_of_a_file_without_a_recording_is_one_error_line(tmp_path):
    import rerun.blueprint as rrb

    from cab_core.errors import RecordError

    path = tmp_path / "layout.rbl"  # a blueprint: a store, but no recording
    rrb.Blueprint(rrb.Spatial3DView(origin="/world")).save("cab", path)
    with pytest.raises(RecordError, match=r"layout\.rbl: 0 recordings in the file, expected one$"):
        Recording(path)
