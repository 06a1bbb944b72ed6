"""``cab-suite-check --planner NAME``: every attempt composed with that planner; an unknown one is a
usage error naming the installed planners."""
from __future__ import annotations

import subprocess
import sys

from cab_core.sweep.supervisor import attempt_configs


def test_attempts_are_composed_with_the_chosen_planner(tmp_path):
    job = ("click_bell", 0, "oracle", str(tmp_path), "mujoco")
    assert attempt_configs([job], False, planner="pin")[0]["planner"]["name"] == "pin"


def test_unknown_planner_is_a_usage_error(tmp_path):
    r = subprocess.run([sys.executable, "-c", "from cab_core.apps.suitecheck import main; main()",
                        "--planner", "nope", "--sim", "mujoco", "--out", str(tmp_path)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("cab-suite-check: unknown planner 'nope'; installed: ")
    assert "pin" in line.split("installed: ")[1].split(", ")
