"""The command-line surface, run as a user would: subprocesses of the installed entry points."""
import json
import os
import subprocess
import sys

import pytest

from cab_core.tools import tool_names

BIN = os.path.dirname(sys.executable)


def run(args, cwd, env=None, timeout=600):
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([os.path.join(BIN, args[0])] + args[1:], cwd=cwd, env=e, capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.sim
def test_plus_groups_as_documented(tmp_path):
    r = run(["cab", "+sim=sapien", "+model=idle", "task=open_microwave", f"hydra.run.dir={tmp_path}/d"], tmp_path)
    assert r.returncode == 0, r.stderr
    res = json.loads((tmp_path / "d" / "result.json").read_text())
    assert (res["task"], res["model"], res["sim"]) == ("open_microwave", "idle", "sapien")
    assert res["verdict"]["success"] is False


def test_unknown_option_lists_choices(tmp_path):
    r = run(["cab", "model=nonexistent", f"hydra.run.dir={tmp_path}/d"], tmp_path)
    assert r.returncode != 0
    assert "nonexistent" in r.stderr and "oracle" in r.stderr and "idle" in r.stderr
    assert not (tmp_path / "d" / "result.json").exists()


@pytest.mark.sim
def test_renderer_that_cannot_start_is_diagnosed(tmp_path):
    r = run(["cab", "model=idle", f"hydra.run.dir={tmp_path}/d"], tmp_path,
            env={"VK_ICD_FILENAMES": str(tmp_path / "missing_icd.json"), "VK_DRIVER_FILES": str(tmp_path / "missing_icd.json")})
    assert r.returncode == 3, (r.returncode, r.stdout, r.stderr)
    assert "renderer unavailable" in r.stderr
    assert "mesa-vulkan-drivers" in r.stderr


def test_schemas_command_prints_every_tool(tmp_path):
    r = run(["cab-schemas"], tmp_path)
    assert r.returncode == 0, r.stderr
    names = [t["name"] for t in json.loads(r.stdout)]
    assert names == tool_names()  # the registry's tools, in its order
    assert {"run_code", "done", "move_delta", "capture_head", "plane_intersect"} <= set(names)
    one = json.loads(run(["cab-schemas", "move_delta"], tmp_path).stdout)
    assert one[0]["parameters"]["properties"]["arm"]
    assert run(["cab-schemas", "nope"], tmp_path).returncode == 2


@pytest.mark.sim
@pytest.mark.slow
def test_bench_prints_its_figures(tmp_path):
    out = tmp_path / "bench.json"
    r = run(["cab-bench", "-n", "3", "--out", str(out)], tmp_path)
    assert r.returncode == 0, r.stderr
    for line in ("capture_head", "get_arm_pose", "reset", "motion wall s per sim s", "video after attempt s per sim s",
                 "raw head render p50", "ratio motion_wall_per_sim_s_over_raw_physics"):
        assert line in r.stdout
    data = json.loads(out.read_text())
    assert data["motion"]["sim_s"] > 0 and data["raw"]["step_rate_hz"] > 0
    assert data["motion"]["video_after_attempt_s_per_sim_s"] > 0  # recording on: the video is rendered after
    assert set(data["targets"]) == {"non_image_tools_p50_le_5ms", "capture_head_p50_le_60ms", "motion_ge_3x_realtime",
                                    "motion_le_2x_raw_physics", "reset_le_3s"}


@pytest.mark.sim
def test_gallery_renders_initial_scenes(tmp_path):
    r = run(["cab-gallery", "--out", "gal", "--tasks", "stack_blocks_three"], tmp_path)
    assert r.returncode == 0, r.stderr
    from PIL import Image

    img = Image.open(tmp_path / "gal" / "stack_blocks_three.png")
    assert img.size == (640, 480)
    page = (tmp_path / "gal" / "README.md").read_text()
    assert "![stack_blocks_three](stack_blocks_three.png)" in page
    assert "Regenerate with `cab-gallery --out gal`." in page and str(tmp_path) not in page


@pytest.mark.sim
@pytest.mark.parametrize("sim", ["sapien", "mujoco", "pybullet"])
def test_an_attempt_prints_one_line_on_every_simulator(sim, tmp_path):
    """No banner of a simulator's C code (PyBullet's build time and ``argv[0]=``) nor a library's
    INFO record (PyOpenGL's accelerator note, under MuJoCo) reaches the newcomer's terminal: the
    attempt's summary line, and only on a machine whose cache folder is still empty, SAPIEN's note
    that it generated its BRDF table (once per machine, with its cost)."""
    r = run(["cab", "task=click_bell", f"sim={sim}", "model=idle", "record.video=false", "hydra.run.dir=out"], tmp_path)
    assert r.returncode == 0, r.stderr
    out = (r.stdout + r.stderr).splitlines()
    once = [line for line in out[:-1] if sim == "sapien" and "SAPIEN's BRDF table for this machine: generated" in line]
    assert out[:-1] == once[:1], out
    assert out[-1].startswith(f"cab: click_bell seed=0 attempt=1 model=idle sim={sim}: success=False"), out


@pytest.mark.parametrize("model,var", [("opus5", "ANTHROPIC_API_KEY"), ("gpt56", "OPENAI_API_KEY")])
def test_missing_key_is_one_line_before_any_simulator(model, var, tmp_path):
    env = {k: "" for k in ("ANTHROPIC_API_KEY", "OPENAI_API_KEY", "GEMINI_API_KEY", "GOOGLE_API_KEY")}
    e = {k: v for k, v in os.environ.items() if k not in env}
    r = subprocess.run([os.path.join(BIN, "cab"), "+sim=sapien", f"+model={model}", f"hydra.run.dir={tmp_path}/d"],
                       cwd=tmp_path, env=e, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and var in lines[0], r.stderr
    assert not (tmp_path / "d" / "events.jsonl").exists()  # nothing was built
