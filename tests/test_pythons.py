"""scripts/find-python.sh, the interpreter that scripts/install.sh sets cab up on for ``PYTHON=...`` and
that scripts/check-pythons.sh takes for each version: a command or path that runs is used as it is; a
version (``3.13``, ``python3.13``) that is not on PATH is the newest plain CPython release of it under
pyenv; anything else is one line and exit status 1."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "find-python.sh"


def find(arg: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", str(SCRIPT), arg], capture_output=True, text=True, timeout=60,
                          env=env if env is not None else os.environ.copy())


def fake_pyenv(root: Path, versions: list[str]) -> None:
    """A pyenv root with an executable ``bin/python<major.minor>`` in each of ``versions``."""
    for v in versions:
        bin_dir = root / "versions" / v / "bin"
        bin_dir.mkdir(parents=True)
        exe = bin_dir / f"python{'.'.join(v.split('.')[:2])}"
        exe.write_text("#!/bin/sh\n")
        exe.chmod(0o755)


def test_a_path_that_runs_is_the_interpreter_it_runs():
    r = find(sys.executable)
    assert r.returncode == 0, r.stderr
    assert r.stdout == sys.executable + "\n"


# 3.97 stands for a version installed under pyenv but not on PATH (pyenv's shim refuses to run it)
@pytest.mark.parametrize("arg", ["3.97", "python3.97"])
def test_a_version_not_on_path_is_the_newest_pyenv_release_of_it(arg, tmp_path):
    fake_pyenv(tmp_path, ["3.97.2", "3.97.10", "3.97.11t", "3.96.9", "3.97.12-dev"])
    env = {"PATH": "/usr/bin:/bin", "PYENV_ROOT": str(tmp_path)}
    r = find(arg, env)
    assert r.returncode == 0, r.stderr
    assert r.stdout == f"{tmp_path}/versions/3.97.10/bin/python3.97\n"  # 10 > 2; free-threaded and dev builds left out


@pytest.mark.parametrize("arg", ["3.98", "python3.98", "/no/such/python"])
def test_an_interpreter_found_nowhere_is_one_line_and_status_1(arg, tmp_path):
    fake_pyenv(tmp_path, ["3.97.2"])
    r = find(arg, {"PATH": "/usr/bin:/bin", "PYENV_ROOT": str(tmp_path)})
    assert r.returncode == 1
    assert r.stdout == ""
    assert r.stderr == f"no Python interpreter '{arg}': not on PATH, nor installed under pyenv\n"
