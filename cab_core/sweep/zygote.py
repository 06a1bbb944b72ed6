"""A fork server for a sweep's warm workers: their imported libraries shared copy-on-write.

Each slot of a sweep (a thread of ``cab -m`` under cab's launcher, a joblib worker, or a thread of
``cab-suite-check``) keeps a warm worker
(``cab_core.sweep.worker``). Started as fresh interpreters, N workers each import the engine, the
simulator and the model's client library and hold N private copies of them (about 130 MiB each with
a physics engine and a provider's SDK). Forked from one process that has imported them (this module's
server, one per sweep), they share those pages: a page is copied only when a worker writes it, and the
server freezes its objects out of the garbage collector's reach (``gc.freeze``) so that collections in a
worker do not write to them.

The server listens on an abstract Unix socket named from what must be equal for two workers to share
it: the interpreter, the process group (one command line: a ``cab -m`` sweep and any launcher processes)
and the environment (thread counts and the renderer's variables are read at import). The first
supervisor that wants a worker starts it; the others connect. A request names the plugin packages to
import (the simulator's, robot's, planner's, harness's and the task suite's, every submodule: their heavy imports sit in submodules,
never in the package's ``__init__``) and hands over the worker's standard input, output and error;
the server imports, forks, and tells the requester the worker's process id, later its exit status.
No renderer, physics world or thread exists in the server when it forks: plugins create them when an
attempt runs. The server leaves when it has had no worker for ``IDLE_S`` seconds.

Importing is not all a worker would otherwise do privately: loading a shared library (a GL or Vulkan
driver and the compiler it links: relocations written into tens of MiB of pages), reading a file
into memory, building a table. A plugin package may hand that to the server with the optional hook
:data:`HOOK`, a function of its top-level module called with no argument once in the server, after
its imports and before the first fork (``docs/plugins.md``). It must start no thread, open no
device and create no context (the server refuses to fork once a second thread runs); a hook that
raises is skipped, and every worker of that package tells why on its standard error (its log).

A worker forked here is not its supervisor's child: it leads its own session (the supervisor's
``kill_group`` kills it and what it started), and it dies with its supervisor by watching the
supervisor's process (a pidfd), as a spawned worker does with ``PR_SET_PDEATHSIG``. Where anything of
this fails (no server can start, an import kills it), the supervisor starts its worker as a fresh
interpreter instead (:func:`fork_worker` returns None).
"""
from __future__ import annotations

import gc
import hashlib
import importlib
import json
import os
import pkgutil
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

IDLE_S = 10.0  # the server leaves after this long without a worker or a request
START_TIMEOUT_S = 120.0  # a request's wait for the server (its start and imports, under load)
WORKER_MODULE = "cab_core.sweep.worker"
HOOK = "cab_preload"  # a plugin package's optional preparation of what its forked workers share
_BASE = ("cab_core.attempt.runner", WORKER_MODULE)  # what every worker imports


def address(env: dict) -> str:
    """The server's abstract socket name for a supervisor with this environment."""
    from cab_core.sweep.protocol import PARENT_ENV

    same = {k: v for k, v in env.items() if k != PARENT_ENV}
    key = json.dumps([sys.executable, os.getuid(), os.getpgid(0), sorted(same.items())])
    return "\0cab-zygote-" + hashlib.sha256(key.encode()).hexdigest()[:24]


# -- the supervisor's side ------------------------------------------------------------------------


class ForkedProcess:
    """A worker forked by the server, as much of ``subprocess.Popen`` as a supervisor uses: ``pid``,
    ``poll``, ``wait`` and ``returncode`` (the server reports the exit status on the request's
    connection; if the server is gone, the worker's end is seen on a pidfd and its status is 1)."""

    def __init__(self, conn: socket.socket, pid: int):
        self.pid = pid
        self.returncode: int | None = None
        self._conn = conn
        try:
            self._pidfd: int | None = os.pidfd_open(pid)
        except OSError:  # gone already: the server's report says how it ended
            self._pidfd = None

    def _status(self, timeout: float | None) -> int | None:
        waiting: list[Any] = [self._conn]
        ready, _, _ = select.select(waiting, [], [], timeout)
        if not ready:
            return None
        msg = self._conn.recv(256)
        if msg.startswith(b"exit "):
            return int(msg.split()[1])
        # the server is gone without a word: wait for the worker itself
        if self._pidfd is not None:
            ready, _, _ = select.select(waiting[:0] + [self._pidfd], [], [], timeout)
            if not ready:
                self._conn = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)  # never readable again
                return None
        return 1

    def poll(self) -> int | None:
        return self.wait(0.0, raise_timeout=False)

    def wait(self, timeout: float | None = None, raise_timeout: bool = True) -> int | None:
        if self.returncode is None:
            self.returncode = self._status(timeout)
            if self.returncode is not None:
                self._conn.close()
                if self._pidfd is not None:
                    os.close(self._pidfd)
                    self._pidfd = None
            elif raise_timeout:
                raise subprocess.TimeoutExpired(f"forked worker {self.pid}", timeout or 0.0)
        return self.returncode


def _connect(name: str, env: dict) -> socket.socket | None:
    started = False
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        s = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            s.connect(name)
            return s
        except OSError:
            s.close()
        if not started:  # several may start one at once: the first to bind serves, the others leave
            subprocess.Popen([sys.executable, "-m", "cab_core.sweep.zygote", name[1:]], env=env,
                             stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True)
            started = True
        time.sleep(0.05)
    return None


def fork_worker(env: dict, preload: Sequence[str], stdin: int, stdout: int, stderr: int) -> ForkedProcess | None:
    """A warm worker forked by this sweep's server with ``env``, the packages ``preload`` imported and
    the three descriptors as its standard streams (the caller closes its copies); None when no server
    could serve the request (start a fresh interpreter instead)."""
    from cab_core.sweep.protocol import PARENT_ENV

    conn = _connect(address(env), env)
    if conn is None:
        return None
    try:
        req = json.dumps({"env": env, "preload": list(preload), "supervisor": int(env[PARENT_ENV])}).encode()
        socket.send_fds(conn, [req], [stdin, stdout, stderr])
        ready, _, _ = select.select([conn], [], [], START_TIMEOUT_S)
        msg = conn.recv(256) if ready else b""
    except OSError:
        msg = b""
    if not msg.startswith(b"pid "):
        conn.close()
        return None
    return ForkedProcess(conn, int(msg.split()[1]))


# -- the server -----------------------------------------------------------------------------------


def _imported_by(module: object) -> set[str]:
    """The top-level packages a module's source imports anywhere, in functions too (a plugin imports
    its simulator, planner or client library where it first needs it)."""
    import ast

    try:
        tree = ast.parse(Path(str(getattr(module, "__file__", "") or "")).read_text())
    except (OSError, SyntaxError, ValueError):
        return set()
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module.split(".")[0])
    return out


def _preload(package: str) -> str | None:
    """Import ``package`` as :func:`_import_all` does, then call its :data:`HOOK` if it has one.
    Returns what went wrong with the hook (one line), None when nothing did or there is none."""
    _import_all(package)
    hook = getattr(sys.modules.get(package), HOOK, None)
    if hook is None:
        return None
    try:
        hook()
    except Exception as e:  # noqa: BLE001 (a failed preparation costs memory, never the worker)
        return f"cab fork server: {package}.{HOOK}() failed and was skipped: {type(e).__name__}: {e}"
    return None


def _import_all(package: str) -> None:
    """Import a package, every module below it and what their code imports (in functions too); a
    module that cannot be imported is left out."""
    try:
        pkg = importlib.import_module(package)
    except Exception:  # noqa: BLE001 (the worker imports it again and reports the error)
        return
    modules = [pkg]
    for info in pkgutil.walk_packages(getattr(pkg, "__path__", []), package + ".", onerror=lambda _: None):
        if info.name.rsplit(".", 1)[-1] in ("__main__", "conftest") or ".tests" in info.name:
            continue
        try:
            modules.append(importlib.import_module(info.name))
        except Exception:  # noqa: BLE001 (optional dependencies of one module)
            continue
    for name in sorted(set().union(*(_imported_by(m) for m in modules)) - set(sys.modules)):
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001 (an optional dependency)
            continue


def _watch_supervisor(pid: int) -> None:
    """Kill this worker's process group when the supervisor ``pid`` ends."""
    try:
        fd = os.pidfd_open(pid)
    except OSError:
        os._exit(1)

    def watch() -> None:
        select.select([fd], [], [])
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, name="supervisor-watch", daemon=True).start()


def _child(req: dict, fds: list[int], keep: list[int], notes: Sequence[str] = ()) -> None:
    """In the forked worker: become the worker the request asked for (``notes``: lines for its
    standard error first); never returns."""
    code = 1
    try:
        for fd in keep:
            os.close(fd)
        os.setsid()
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
            os.close(fd)
        for line in notes:
            print(line, file=sys.stderr, flush=True)
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        os.environ.clear()
        os.environ.update(req["env"])
        _watch_supervisor(req["supervisor"])
        # the worker's module by name, as the supervisor starts a fresh one (``-m cab_core.sweep.worker``):
        # the server, like the supervisor, sits below what an attempt runs
        code = importlib.import_module(WORKER_MODULE).serve()
    except BaseException:  # noqa: BLE001 (told on stderr, the worker's log; the status says it failed)
        import traceback

        traceback.print_exc()
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)


def serve(name: str) -> int:
    """The server's loop: requests in, workers out, exit statuses reported."""
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        listener.bind("\0" + name)
    except OSError:  # another supervisor's server won the race
        return 0
    listener.listen(64)
    for m in _BASE:
        importlib.import_module(m)
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    children: dict[int, socket.socket] = {}
    loaded: dict[str, str | None] = {}  # package -> what went wrong with its hook
    while True:
        waiting: list[Any] = [listener, wake_r]
        ready, _, _ = select.select(waiting, [], [], None if children else IDLE_S)
        if not ready and not children:
            return 0
        if wake_r in ready:
            try:
                while os.read(wake_r, 512):
                    pass
            except BlockingIOError:
                pass
        while children:
            try:
                pid, status = os.waitpid(-1, os.WNOHANG)
            except ChildProcessError:
                break
            if pid == 0:
                break
            conn = children.pop(pid, None)
            if conn is not None:
                try:
                    conn.send(f"exit {os.waitstatus_to_exitcode(status)}".encode())
                except OSError:
                    pass
                conn.close()
        if listener not in ready:
            continue
        conn, _ = listener.accept()
        try:
            msg, fds, _, _ = socket.recv_fds(conn, 1 << 20, 3)
            req = json.loads(msg)
        except (OSError, ValueError):
            conn.close()
            continue
        if len(fds) != 3:
            for fd in fds:
                os.close(fd)
            conn.close()
            continue
        for package in req.get("preload", []):
            if package not in loaded:
                loaded[package] = _preload(package)
        notes = [n for p in req.get("preload", []) if (n := loaded.get(p))]
        if len(os.listdir("/proc/self/task")) > 1:  # an import started a thread: a fork would inherit its locks
            for fd in fds:
                os.close(fd)
            try:
                conn.send(b"refused: a thread is running in the fork server")
            except OSError:
                pass
            conn.close()
            continue
        gc.collect()
        gc.freeze()  # what is here now is shared with every worker: no collection writes to it
        pid = os.fork()
        if pid == 0:
            _child(req, fds, [listener.fileno(), wake_r, wake_w, conn.fileno(),
                              *(c.fileno() for c in children.values())], notes)
        for fd in fds:
            os.close(fd)
        try:
            conn.send(f"pid {pid}".encode())
            children[pid] = conn
        except OSError:  # the requester is gone: so is the worker's input
            conn.close()


def main() -> int:
    return serve(sys.argv[1])


if __name__ == "__main__":
    sys.exit(main())

