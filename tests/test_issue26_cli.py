"""Issue 26, items 3 and 8 (the ``cab`` command): invalid ``sandbox.*``/``record.*`` values, output
folders that cannot be written, refused commands that leave no folder, a torn parent forked,
``cab --version`` and ``cab --help``. Each case is one line on stderr with exit status 2 (or the
documented output), before anything runs. The ``cab`` cases run the installed entry point."""
import json
import os
import subprocess
from importlib import metadata

import pytest
from hydra import compose, initialize_config_module
from test_cli_mistakes import BIN, cab_refuses, command_line_refusal, refused, run

from cab_core.apps.cli import normalise_overrides
from cab_core.apps.cmdline import check_command_line
from cab_core.attempt.fork import ForkPoint
from cab_core.attempt.runner import attempt_spec
from cab_core.errors import CabError, ConfigError

UNWRITABLE = "/proc/1"  # an existing folder in which no file can be created, even by root


def run_env(args, cwd, **env):
    """``run`` with these environment variables (None: removed)."""
    e = {k: v for k, v in {**os.environ, **env}.items() if v is not None}
    return subprocess.run([os.path.join(BIN, args[0])] + args[1:], cwd=cwd, capture_output=True, text=True,
                          timeout=300, env=e)


# --- item 3: sandbox.* and record.* values, with the command line -----------------------------

BAD_VALUES = [
    ("sandbox.mode=bogus", "sandbox.mode must be one of required, auto, off, got 'bogus'"),
    ("sandbox.timeout_s=-1", "sandbox.timeout_s must be a positive number of seconds (wall clock per run_code "
                             "program), got -1"),
    ("sandbox.memory_mb=0", "sandbox.memory_mb must be an integer of at least 256 (MiB: the address space of the "
                            "run_code process), got 0"),
    ("record.video_size=[1,2,3]", "record.video_size must be [width, height]: two integers from 8 to 4096 "
                                  "(pixels), got [1, 2, 3]"),
    ("record.video_every_steps=0", "record.video_every_steps must be a positive integer (physics steps per video "
                                   "frame; record.video=false records no video), got 0"),
]


@pytest.mark.parametrize("override, line", BAD_VALUES)
def test_invalid_sandbox_and_record_values_are_one_line_before_anything_runs(tmp_path, override, line):
    cab_refuses(tmp_path, [override, "model=idle", "sim=mujoco"], f"cab: {line}")


@pytest.mark.parametrize("override, line", BAD_VALUES)
def test_every_value_of_a_sweep_is_checked(override, line):
    key, value = override.split("=", 1)
    good = {"sandbox.mode": "auto", "sandbox.timeout_s": "60", "sandbox.memory_mb": "4096",
            "record.video_size": "[640,480]", "record.video_every_steps": "10"}[key]
    sweep = f"{key}=choice({good},{value})" if value.startswith("[") else f"{key}={good},{value}"
    assert command_line_refusal(["-m", sweep]) == line


@pytest.mark.parametrize("override, line", [
    ("sandbox.timeout_s=0", "sandbox.timeout_s must be a positive number of seconds (wall clock per run_code program), "
                            "got 0"),
    ("sandbox.timeout_s=true", "sandbox.timeout_s must be a positive number of seconds (wall clock per run_code "
                               "program), got True"),
    ("sandbox.memory_mb=1.5", "sandbox.memory_mb must be an integer of at least 256 (MiB: the address space of the "
                              "run_code process), got 1.5"),
    ("record.video_size=[320,0]", "record.video_size must be [width, height]: two integers from 8 to 4096 (pixels), "
                                  "got [320, 0]"),
    ("record.video=maybe", "record.video must be true or false, got 'maybe'"),
    ("seed=abc", "seed must be a non-negative integer, or null (the task's fixed seed), got 'abc'"),
    ("seed=-2", "seed must be a non-negative integer, or null (the task's fixed seed), got -2"),
    ("attempt=0", "attempt must be a positive integer (1, 2, ...: the repetition of the attempt), got 0"),
])
def test_other_out_of_range_values(override, line):
    assert command_line_refusal([override]) == line


def test_documented_values_pass():
    check_command_line(["sandbox.mode=required", "sandbox.timeout_s=30", "sandbox.timeout_s=2.5", "sandbox.memory_mb=4096",
                        "record.video=false", "record.video_every_steps=10", "record.video_size=[640,480]",
                        "seed=3", "seed=null", "attempt=2"])
    check_command_line(["-m", "sandbox.mode=auto,required,off", "record.video_size=choice([320,240],[64,48])"])


@pytest.mark.parametrize("override, line", BAD_VALUES)
def test_the_composed_configuration_is_checked_too(tmp_path, override, line):
    """A value that reaches the composed config another way (an experiment's or a project's yaml):
    refused when the attempt is specified, before anything starts."""
    with initialize_config_module(version_base=None, config_module="cab_core.conf"):
        cfg = compose(config_name="config", overrides=normalise_overrides(["sim=mujoco", "model=idle", override]))
    with pytest.raises(ConfigError) as e:
        attempt_spec(cfg, tmp_path / "out")
    assert str(e.value) == line
    assert not (tmp_path / "out").exists()


# --- item 8: output folders ------------------------------------------------------------------

def test_an_existing_run_folder_that_cannot_be_written(tmp_path):
    assert os.path.isdir(UNWRITABLE)
    r = run(["cab", "model=idle", "sim=mujoco", f"hydra.run.dir={UNWRITABLE}"], tmp_path)
    assert r.returncode == 2 and r.stdout == "", r.stderr
    assert len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"cab: cannot write in the output folder {UNWRITABLE} (hydra.run.dir): "), r.stderr
    assert os.listdir(tmp_path) == []


def test_a_sweep_folder_that_cannot_be_written(tmp_path):
    (tmp_path / "afile").write_text("")
    r = run(["cab", "-m", f"hydra.sweep.dir={tmp_path}/afile/x", "model=idle", "sim=mujoco"], tmp_path)
    refused(r, f"cab: cannot write in the sweep folder {tmp_path}/afile/x (hydra.sweep.dir): Not a directory")
    r = run(["cab", "-m", f"hydra.sweep.dir={UNWRITABLE}", "model=idle", "sim=mujoco"], tmp_path)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"cab: cannot write in the sweep folder {UNWRITABLE} (hydra.sweep.dir): "), r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


@pytest.mark.parametrize("overrides, line", [
    (["seed=abc"], "cab: seed must be a non-negative integer, or null (the task's fixed seed), got 'abc'"),
    (["attempt=0"], "cab: attempt must be a positive integer (1, 2, ...: the repetition of the attempt), got 0"),
    (["fork.at=3"], "cab: fork.at needs fork.from=<the folder of the attempt to fork>"),
    (["model=opus5"], "cab: ANTHROPIC_API_KEY is not set: model 'opus5' (provider anthropic) needs it in the environment"),
])
def test_a_refused_command_leaves_no_folder(tmp_path, overrides, line):
    """In the default output folder (outputs/<task>/<model>/<sim>/<time>), created by Hydra."""
    r = run_env(["cab", "sim=mujoco", "record.video=false", *overrides], tmp_path, ANTHROPIC_API_KEY=None)
    refused(r, line)
    assert os.listdir(tmp_path) == []


def test_a_refused_attempt_removes_only_what_hydra_created(tmp_path):
    """Refused after Hydra created the folder (the harness's pre-flight): the folders that existed
    before stay, with what they hold; a folder the user named that exists stays too."""
    (tmp_path / "outputs" / "earlier").mkdir(parents=True)
    r = run_env(["cab", "sim=mujoco", "model=opus5"], tmp_path, ANTHROPIC_API_KEY=None)
    assert r.returncode == 2, r.stderr
    assert [p.relative_to(tmp_path).as_posix() for p in sorted(tmp_path.rglob("*"))] == ["outputs", "outputs/earlier"]
    mine = tmp_path / "mine"
    mine.mkdir()
    r = run_env(["cab", "sim=mujoco", "model=opus5", f"hydra.run.dir={mine}"], tmp_path, ANTHROPIC_API_KEY=None)
    assert r.returncode == 2, r.stderr
    assert mine.is_dir()


# --- item 8: a torn parent forked --------------------------------------------------------------

def _torn_parent(d, last: str):
    d.mkdir()
    config = {"task": "click_bell", "seed": 0, "sim": "mujoco", "embodiment": "aloha_agilex", "planner": "pin"}
    events = [{"seq": 1, "kind": "attempt_start", "t_wall": 0.0, "config": config},
              {"seq": 2, "kind": "call", "t_wall": 1.0, "tool": "capture_head", "arguments": {}, "status": None},
              {"seq": 3, "kind": "call", "t_wall": 2.0, "tool": "capture_head", "arguments": {}, "status": None}]
    (d / "events.jsonl").write_bytes(("".join(json.dumps(e) + "\n" for e in events)).encode() + last.encode())
    return d


@pytest.mark.parametrize("last", ['{"seq": 4, "kind": "call", "t_wall": 3.0, "tool": "move_d', '{"seq": 4, "note": "\u00e9'])
def test_a_torn_parent_is_not_forked(tmp_path, last):
    parent = _torn_parent(tmp_path / "parent", last)
    line = (f"fork.from={parent}: events.jsonl line 4 is torn (not valid JSON: the attempt was cut off while writing "
            "it); the parent's records are incomplete, so it is not forked (remove that line to fork the calls before it)")
    if last.endswith("\u00e9"):  # cut inside a multi-byte character
        (parent / "events.jsonl").write_bytes((parent / "events.jsonl").read_bytes()[:-1])
    with pytest.raises(CabError) as e:
        ForkPoint.load(parent, 1)
    assert str(e.value) == line
    assert command_line_refusal([f"fork.from={parent}", "fork.at=1", "model=idle"]) == line
    r = run(["cab", f"fork.from={parent}", "fork.at=1", "model=idle"], tmp_path)
    refused(r, f"cab: {line}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["parent"]


def test_a_whole_last_line_is_not_torn(tmp_path):
    parent = _torn_parent(tmp_path / "parent", '{"seq": 4, "kind": "attempt_end", "t_wall": 3.0}')  # no newline
    assert ForkPoint.load(parent, 2).parent_calls == 2


# --- item 8: --version and --help ------------------------------------------------------------

def test_version_is_cabs_and_its_plugins(tmp_path):
    from cab_core.plugins import distribution_versions

    r = run(["cab", "--version"], tmp_path)
    assert (r.returncode, r.stderr) == (0, ""), r.stderr
    core = metadata.packages_distributions()["cab_core"]
    plugins = {d: v for d, v in distribution_versions().items() if d not in core}
    assert plugins  # the project's plugins are installed beside it
    assert r.stdout.splitlines() == [f"cab {metadata.version(core[0])}", "plugins:",
                                     *(f"  {d} {v}" for d, v in plugins.items())]
    assert "Hydra" not in r.stdout
    assert os.listdir(tmp_path) == []


def test_help_is_titled_cab_and_says_what_the_main_keys_do(tmp_path):
    r = run(["cab", "--help"], tmp_path)
    assert (r.returncode, r.stderr) == (0, ""), r.stderr
    lines = r.stdout.splitlines()
    assert lines[0].startswith("cab: one attempt of an agent at a manipulation task")
    assert "cli" not in r.stdout.split() and "powered by Hydra" not in r.stdout
    keys = [line.split()[0] for line in lines[lines.index("Main keys:") + 1:lines.index("Config groups (group=option):")]
            if line.startswith("  ") and not line.startswith("   ")]
    assert keys == ["task=T", "sim=S", "model=M", "seed=N", "attempt=N", "budget.*", "sandbox.*", "record.*",
                    "randomize=R", "seed_set=NAME", "fork.from=DIR", "experiment=X", "-m"]
    assert "fork.at=K" in r.stdout and "mode=required|auto|off" in r.stdout
    assert any(line.startswith("task: ") and "click_bell" in line for line in lines)  # the groups' options
    assert os.listdir(tmp_path) == []
