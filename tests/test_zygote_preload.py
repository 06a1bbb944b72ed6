"""The fork server's plugin hook (``cab_core.sweep.zygote.HOOK``): called once in the server, after the
package's imports and before its first fork; a hook that raises is skipped and told in the worker's log."""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

from cab_core.sweep import zygote
from cab_core.sweep.protocol import PARENT_ENV

GOOD = '''
import os
from pathlib import Path

RAN = Path(__file__).with_name("ran.txt")


def cab_preload():
    with open(RAN, "a") as f:
        f.write(f"{os.getpid()} {os.getppid()}\\n")
'''

BAD = '''
def cab_preload():
    raise RuntimeError("no driver here")
'''


def _package(root: Path, name: str, source: str) -> Path:
    pkg = root / name
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(source)
    return pkg


def _fork(root: Path, package: str, log: Path) -> tuple[zygote.ForkedProcess, int]:
    """A worker forked by the server of an environment that finds ``root``'s packages, and the write
    end of its input (closed: the worker leaves)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), *sys.path]), PARENT_ENV: str(os.getpid())}
    r, w = os.pipe()
    out = os.open(os.devnull, os.O_WRONLY)
    err = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        proc = zygote.fork_worker(env, [package], r, out, err)
    finally:
        for fd in (r, out, err):
            os.close(fd)
    assert proc is not None, "the fork server refused the worker"
    return proc, w


def _parent(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def test_the_hook_runs_once_in_the_server_before_it_forks(tmp_path):
    pkg = _package(tmp_path / "site", "cab_hook_probe_ok", GOOD)
    servers = []
    for i in range(2):
        proc, stdin = _fork(tmp_path / "site", "cab_hook_probe_ok", tmp_path / f"w{i}.log")
        servers.append(_parent(proc.pid))  # alive until its input closes
        os.close(stdin)
        assert proc.wait(timeout=30) == 0
    lines = (pkg / "ran.txt").read_text().splitlines()
    assert len(lines) == 1  # once, not once a worker
    pid, _ = (int(x) for x in lines[0].split())
    assert servers == [pid, pid]  # in the server, both workers' parent: not in a worker, nor here
    assert not any(line.strip() for i in range(2) for line in (tmp_path / f"w{i}.log").read_text().splitlines())


def test_a_failing_hook_is_skipped_and_told_in_every_workers_log(tmp_path):
    _package(tmp_path / "site", "cab_hook_probe_bad", BAD)
    for i in range(2):
        proc, stdin = _fork(tmp_path / "site", "cab_hook_probe_bad", tmp_path / f"w{i}.log")
        os.close(stdin)
        assert proc.wait(timeout=30) == 0  # forked and ran all the same
        deadline = time.monotonic() + 5
        while not (tmp_path / f"w{i}.log").read_text() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert (tmp_path / f"w{i}.log").read_text().splitlines() == [
            "cab fork server: cab_hook_probe_bad.cab_preload() failed and was skipped: RuntimeError: no driver here"]
