"""The task kit (cab_core.kits, issue 27): a task written on ``SceneTask`` gives its own metadata
and is looked up in no catalog; the kit's modules import only the contracts, errors, geometry,
numerics and one another."""
from __future__ import annotations

import grimp
import numpy as np
import pytest

from cab_core.contracts.scene import Body, Box, Shape
from cab_core.contracts.task import TaskInfo
from cab_core.errors import PluginError
from cab_core.kits.scene import TABLE_TOP_Z, base_scene, pose_list, rand_pose
from cab_core.kits.task import SceneTask

INFO = TaskInfo(name="lift_cube", instruction="Lift the cube.", seed=3, scoring="final", budget_tool_calls=10,
                budget_sim_s=20.0)


class LiftCube(SceneTask):
    info = INFO

    def lay_out(self, rng, top, scene, embodiment):
        pose = rand_pose(rng, (-0.2, 0.2), (-0.1, 0.0), (top + 0.02,))
        scene.bodies.append(Body("cube", [Shape(Box((0.02, 0.02, 0.02)))], pose=tuple(pose), mass=0.05))
        return {"cube": pose_list(pose)}


def test_a_scene_task_takes_its_name_and_metadata_from_its_info():
    task = LiftCube()
    assert LiftCube.name == "lift_cube" and task.info is INFO


def test_build_is_the_base_scene_with_what_lay_out_adds_deterministic_in_the_seed():
    a, b, c = LiftCube().build(3), LiftCube().build(3), LiftCube().build(4)
    assert [x.name for x in a.scene.bodies] == ["table", "wall", "cube"]
    assert a.scene.timestep == base_scene().timestep == 1.0 / 250.0
    assert a.info["task"] == "lift_cube" and a.info["seed"] == 3 and a.info["table_top_z"] == TABLE_TOP_Z
    assert a.info == b.info and a.info["cube"] != c.info["cube"]
    assert a.info["cube"][2] == pytest.approx(TABLE_TOP_Z + 0.02)
    assert np.isclose(np.linalg.norm(a.info["cube"][3:]), 1.0)


@pytest.mark.parametrize("name", ["lift_cube", "click_bell"])
def test_without_info_it_is_refused_even_under_a_catalog_name(name):
    """No catalog lookup: a name the CodeActionBench catalog has gives a SceneTask nothing."""
    cls = type("NoInfo", (SceneTask,), {"name": name, "__module__": "my_plugin.tasks"})
    with pytest.raises(PluginError) as e:
        cls()
    assert str(e.value) == (
        f"task {name!r} (my_plugin.tasks.NoInfo, a SceneTask) has no metadata: declare it on the class as "
        "info = TaskInfo(name=..., instruction=..., seed=..., scoring=..., budget_tool_calls=..., budget_sim_s=...) "
        "(cab_core.contracts.task), or set self.info in __init__")


def test_the_kits_import_only_the_contracts_errors_geometry_numerics_and_one_another():
    graph = grimp.build_graph("cab_core", cache_dir=None)
    allowed = ("cab_core.contracts", "cab_core.errors", "cab_core.geometry", "cab_core.numerics", "cab_core.kits")
    task_kit = [m for m in graph.modules if m.startswith("cab_core.kits.")
                and m.split(".")[2] in ("scene", "assets", "task", "margins", "oracle", "stages")]
    assert len(task_kit) == 6
    bad = {(m, i) for m in task_kit for i in graph.find_upstream_modules(m)
           if not any(i == a or i.startswith(a + ".") for a in allowed)}
    assert bad == set()
