"""The host side of run_code: one persistent, confined child per attempt, reached by framed RPC.

The host (this module, in the episode process) owns everything privileged. The child only ever asks:
"call tool T with these keyword arguments", "give me the pixels of obs_id X", "here is printed text",
"the program finished". Each tool call is handed to ``dispatch`` in the thread that called
:meth:`Sandbox.run`, synchronously, so validation and budgets are exactly those of a direct call.
"""
from __future__ import annotations

import json
import keyword
import logging
import os
import queue
import select
import shutil
import signal
import struct
import subprocess
import tempfile
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cab_core.errors import CabError, ConfigError, SandboxUnavailable, ToolArgumentError
from cab_core.sandbox import confine
from cab_core.sandbox.truncate import NON_FINITE_KEY, cap_result, finite_json, json_size, non_finite_note

log = logging.getLogger("cab.sandbox")

_HEADER = struct.Struct(">II")
_MAX_CHILD_FRAME = 16 * 1024 * 1024  # a program's tool arguments or result value, never more
_RUNNER_SRC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "guest.py")
_PREBOUND = {"np", "math", "print", "load_image", "result"}
_NOT_BOUND = {"run_code", "done"}
FILESYSTEM_POLICY = "structurally_denied"
_RESET_TEXT = ("The sandbox was restarted: variables and functions from earlier run_code calls are gone "
               "(namespace_reset).")


@dataclass
class SandboxConfig:
    """run_code limits and confinement. Defaults are the benchmark's (FACTS A.7)."""

    mode: str = "auto"  # "required": bubblewrap + seccomp or SandboxUnavailable; "auto": best available; "off": tests only
    timeout_s: float = 180.0  # wall clock per program, tool calls included; exceeded: child killed, namespace reset
    max_internal_calls: int = 500  # tool calls one program may make
    stdout_cap: int = 8000  # characters of printed output returned
    result_cap_bytes: int = 32768  # model-visible result JSON, truncated deterministically beyond this
    max_images: int = 6  # images attached to one result
    memory_mb: int = 2048  # RLIMIT_AS of the child
    spawn_timeout_s: float = 30.0
    cpu_s: int = 3600  # RLIMIT_CPU: CPU seconds one child may use over its whole life
    bwrap: str = "bwrap"  # bubblewrap executable (name on PATH or a path); "" = unavailable
    hide_paths: tuple[str, ...] = ()  # extra host paths to mask should they lie under a mounted system dir
    stop_grace_s: float = 2.0  # after the attempt ends mid-program, time the program gets to unwind

    def __post_init__(self) -> None:
        if self.mode not in ("auto", "required", "off"):
            raise ConfigError(f"sandbox mode must be 'auto', 'required' or 'off', not {self.mode!r}")
        for name in ("timeout_s", "max_internal_calls", "stdout_cap", "result_cap_bytes", "memory_mb",
                     "spawn_timeout_s", "cpu_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"sandbox.{name} must be positive, got {getattr(self, name)!r}")
        if self.max_images < 0 or self.stop_grace_s < 0:
            raise ConfigError("sandbox.max_images and sandbox.stop_grace_s must not be negative")
        self.hide_paths = tuple(self.hide_paths)


@dataclass
class DispatchResult:
    """What the host's dispatch returns for one tool call made by a program."""

    payload: dict  # the tool result as the agent would see it (JSON-able)
    obs_ids: list[str] = field(default_factory=list)  # images this result carries
    aborted: bool = False  # status ABORTED: kill the child, reset the namespace, stop the program
    ended: bool = False  # the attempt ended (budget): stop the program, return the partial trace


class _ChildGone(Exception):
    pass


class _Timeout(Exception):
    pass


class _ProtocolError(Exception):
    pass


class _SpawnError(Exception):
    pass


# ------------------------------------------------------------------------------------ plumbing
def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    raise TypeError(f"tool payload is not JSON-serialisable: {type(obj).__name__}")


def _no_constant(name: str):
    raise ValueError(f"{name} is not JSON")


class _Channel:
    """Length-prefixed frames over the child's pipes, with deadlines (poll, non-blocking fds)."""

    def __init__(self, proc: subprocess.Popen):
        assert proc.stdout is not None and proc.stdin is not None, "the child is started with pipes"
        self.rfd = proc.stdout.fileno()
        self.wfd = proc.stdin.fileno()
        os.set_blocking(self.rfd, False)
        os.set_blocking(self.wfd, False)
        self.buf = bytearray()

    def _wait(self, fd: int, events: int, deadline: float) -> None:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            raise _Timeout()
        poller = select.poll()
        poller.register(fd, events)
        if not poller.poll(max(1, int(remaining * 1000))):
            if time.monotonic() >= deadline:
                raise _Timeout()

    def send(self, msg: dict, blob=b"", deadline: float | None = None) -> None:
        data = json.dumps(msg, separators=(",", ":"), default=_json_default).encode("utf-8")
        blob = memoryview(blob).cast("B") if blob else memoryview(b"")
        deadline = deadline if deadline is not None else time.monotonic() + 30.0
        for part in (memoryview(_HEADER.pack(len(data), len(blob)) + data), blob):
            while part:
                try:
                    n = os.write(self.wfd, part)
                    part = part[n:]
                except BlockingIOError:
                    self._wait(self.wfd, select.POLLOUT, deadline)
                except (BrokenPipeError, ConnectionResetError, OSError) as exc:
                    raise _ChildGone(str(exc)) from None

    def recv(self, deadline: float) -> tuple[dict, bytes]:
        while True:
            if len(self.buf) >= _HEADER.size:
                jl, bl = _HEADER.unpack_from(self.buf)
                if jl > _MAX_CHILD_FRAME or bl:
                    raise _ProtocolError(f"malformed frame from the sandbox (json {jl} B, blob {bl} B)")
                if len(self.buf) >= _HEADER.size + jl:
                    data = bytes(self.buf[_HEADER.size:_HEADER.size + jl])
                    del self.buf[:_HEADER.size + jl]
                    try:  # strict: the guest never sends NaN or Infinity, so one is a broken frame
                        msg = json.loads(data, parse_constant=_no_constant)
                    except ValueError as exc:
                        raise _ProtocolError(f"unreadable frame from the sandbox: {exc}") from None
                    if not isinstance(msg, dict) or not isinstance(msg.get("op"), str):
                        raise _ProtocolError("frame without an op from the sandbox")
                    return msg, b""
            try:
                chunk = os.read(self.rfd, 1 << 20)
            except BlockingIOError:
                self._wait(self.rfd, select.POLLIN, deadline)
                continue
            except OSError as exc:
                raise _ChildGone(str(exc)) from None
            if not chunk:
                raise _ChildGone("end of file")
            self.buf += chunk


class _Spawner:
    """A thread that lives as long as the Sandbox and starts every child.

    The child (or bubblewrap) is killed when the thread that forked it exits (``PR_SET_PDEATHSIG``
    follows the parent *thread*). Forking from this long-lived thread keeps a host that calls
    :meth:`Sandbox.run` from short-lived worker threads from killing its own sandbox by accident.
    """

    def __init__(self):
        self._q: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._loop, name="cab-sandbox-spawner", daemon=True)
        self._thread.start()

    def _loop(self):
        while True:
            item = self._q.get()
            if item is None:
                return
            fn, box, done = item
            try:
                box.append((True, fn()))
            except BaseException as exc:  # noqa: BLE001 - handed back to the caller
                box.append((False, exc))
            done.set()

    def call(self, fn):
        box: list = []
        done = threading.Event()
        self._q.put((fn, box, done))
        done.wait()
        ok, value = box[0]
        if ok:
            return value
        raise value

    def stop(self):
        self._q.put(None)


class _Child:
    def __init__(self, proc: subprocess.Popen, channel: _Channel, ready: dict, spawn_s: float):
        self.proc = proc
        self.channel = channel
        self.ready = ready
        self.spawn_s = spawn_s

    def kill(self) -> None:
        _kill_proc(self.proc)

    def exit_description(self) -> str:
        code = self.proc.poll()
        if code is None:
            return "still running"
        if code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit status {code}"


def _kill_proc(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.kill()
    except ProcessLookupError:
        pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:  # pragma: no cover - SIGKILL does not fail
        log.error("sandbox child %s did not exit after SIGKILL", proc.pid)
    for f in (proc.stdin, proc.stdout):
        try:
            if f:
                f.close()
        except OSError:
            pass


class _Owned:
    """What must be released even if the Sandbox is never closed (weakref.finalize target)."""

    def __init__(self, workdir: str, spawner: _Spawner):
        self.workdir = workdir
        self.spawner = spawner
        self.proc: subprocess.Popen | None = None

    def release(self):
        if self.proc is not None:
            _kill_proc(self.proc)
            self.proc = None
        self.spawner.stop()
        shutil.rmtree(self.workdir, ignore_errors=True)


@dataclass
class _RunState:
    calls: int = 0
    trace: list = field(default_factory=list)
    trace_full: list = field(default_factory=list)
    obs_ids: list = field(default_factory=list)
    image_events: list = field(default_factory=list)
    stdout: list = field(default_factory=list)
    stdout_len: int = 0
    done: dict | None = None
    aborted: tuple | None = None  # (index, tool, payload)
    ended: bool = False
    reset_reason: str | None = None
    error: str | None = None
    timed_out: bool = False
    limit_s: float = 0.0


def _pick(payload: dict, key: str):
    if key in payload:
        return payload[key]
    achieved = payload.get("achieved")
    if isinstance(achieved, dict) and key in achieved:
        return achieved[key]
    return None


# ----------------------------------------------------------------------------------- the sandbox
class Sandbox:
    """A persistent, confined Python namespace for run_code programs (FACTS A.7).

    ``tool_names``: the robot tools delivered to the agent; each becomes a keyword-only function in
    the program (``run_code`` and ``done`` never do). ``dispatch(name, kwargs)`` runs one tool for a
    program, in the calling thread, and returns a :class:`DispatchResult`. ``load_image(obs_id)``
    returns an HxWx3 uint8 array; ``KeyError``, ``ToolArgumentError`` or ``ValueError`` for an id it
    cannot serve becomes a ``ValueError`` in the program (anything else is a host fault and propagates).

    Attributes for the records: ``confinement`` ("bubblewrap" | "rlimits" | "none"),
    ``confinement_layers`` (each OS layer and whether it was applied), ``confinement_note`` (why a
    weaker confinement runs), ``spawn_s``, and after each run ``last_run_record`` (the full internal
    trace with arguments and timings, which the model-visible result leaves out).
    """

    def __init__(self, tool_names: list[str], dispatch: Callable[[str, dict], DispatchResult],
                 load_image: Callable[[str], np.ndarray], config: SandboxConfig | None = None,
                 *, _python_layer: bool = True):
        # ``_python_layer=False`` (tests only) skips the AST policy and the restricted builtins, to
        # show that the OS confinement holds on its own. No configuration file can reach it.
        self.config = config or SandboxConfig()
        tools = []
        for name in dict.fromkeys(tool_names):
            if name in _NOT_BOUND:
                continue
            if not (isinstance(name, str) and name.isidentifier() and not keyword.iskeyword(name)) \
                    or name in _PREBOUND or name.startswith("_"):
                raise ConfigError(f"cannot bind tool {name!r} as a function in run_code programs")
            tools.append(name)
        self.tool_names = tools
        self._dispatch = dispatch
        self._load_image = load_image
        self._python_layer = _python_layer
        self._lock = threading.RLock()
        self._closed = False
        self._child: _Child | None = None
        self._plan: confine.LaunchPlan | None = None
        self.confinement: str | None = None
        self.confinement_layers: dict[str, str] = {}
        self.confinement_note: str = ""
        self.spawn_s: float | None = None
        self.spawns = 0
        self.last_run_record: dict = {}
        workdir = tempfile.mkdtemp(prefix="cab-sandbox-")
        os.chmod(workdir, 0o700)
        shutil.copyfile(_RUNNER_SRC, os.path.join(workdir, "guest.py"))
        os.chmod(os.path.join(workdir, "guest.py"), 0o444)
        self._workdir = workdir
        self._owned = _Owned(workdir, _Spawner())
        self._finalizer = weakref.finalize(self, self._owned.release)
        try:
            self._start()
        except BaseException:
            self.close()
            raise

    # -- life cycle
    def __enter__(self) -> Sandbox:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Kill the child and remove the private directory. Safe from another thread while a
        program runs: that run returns at once with ``namespace_reset_reason="closed"``."""
        self._closed = True
        proc = self._owned.proc
        if proc is not None:  # stop a running program now; the running thread cleans up
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        with self._lock:
            self._child = None
            self._finalizer()

    def _start(self) -> None:
        cfg = self.config
        layout = confine.PythonLayout.current()
        if cfg.mode == "off":
            self._plan = confine.plain_plan(self._workdir, layout, os_layers=False)
            try:
                self._child = self._spawn(self._plan)
            except _SpawnError as exc:
                raise SandboxUnavailable(f"the run_code sandbox could not be started: {exc}") from None
            self.confinement = "none"
            self.confinement_note = "mode=off: no OS confinement (tests only)"
            return
        problems = []
        bwrap = confine.find_bwrap(cfg.bwrap)
        if bwrap is None:
            problems.append(f"bubblewrap ({cfg.bwrap or 'disabled'}) was not found")
        else:
            plan = confine.bwrap_plan(bwrap, self._workdir, layout, cfg.hide_paths)
            try:
                child = self._spawn(plan)
            except _SpawnError as exc:
                problems.append(f"bubblewrap could not start the sandbox: {exc}")
            else:
                missing = [k for k in ("seccomp",) if not child.ready["layers"].get(k, "").startswith("ok")]
                if missing and cfg.mode == "required":
                    child.kill()
                    self._owned.proc = None
                    problems.append("seccomp could not be applied: " + child.ready["layers"].get("seccomp", "?"))
                else:
                    self._plan, self._child, self.confinement = plan, child, "bubblewrap"
                    if missing:
                        self.confinement_note = f"seccomp unavailable: {child.ready['layers'].get('seccomp')}"
                    return
        if cfg.mode == "required":
            raise SandboxUnavailable(
                "run_code confinement is required but unavailable: " + "; ".join(problems)
                + ". Install bubblewrap (Debian/Ubuntu: apt-get install bubblewrap) on a kernel that allows "
                "user namespaces, or run with sandbox mode=auto to accept rlimits-only confinement.")
        self._plan = confine.plain_plan(self._workdir, layout, os_layers=True)
        try:
            self._child = self._spawn(self._plan)
        except _SpawnError as exc:
            raise SandboxUnavailable("the run_code sandbox could not be started: " + "; ".join(problems)
                                     + f"; without bubblewrap: {exc}") from None
        self.confinement = "rlimits"
        self.confinement_note = "; ".join(problems) + " -> running with rlimits, seccomp and Landlock where available"
        log.warning("run_code sandbox without bubblewrap: %s", self.confinement_note)

    def _spawn(self, plan: confine.LaunchPlan) -> _Child:
        cfg = self.config
        t0 = time.perf_counter()
        errpath = os.path.join(self._workdir, "child.stderr")
        errfile = open(errpath, "w+b")  # noqa: SIM115 - handed to the child, closed below
        try:
            proc = self._owned.spawner.call(lambda: subprocess.Popen(
                plan.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=errfile,
                cwd=plan.cwd, env=plan.env, close_fds=True, start_new_session=True))
        except OSError as exc:
            errfile.close()
            raise _SpawnError(f"{plan.argv[0]}: {exc}") from None
        errfile.close()
        self._owned.proc = proc
        channel = _Channel(proc)
        init = {
            "op": "init", "tools": self.tool_names, "max_internal_calls": cfg.max_internal_calls,
            "stdout_cap": cfg.stdout_cap, "python_layer": self._python_layer,
            "limits": {"as_bytes": cfg.memory_mb * 1024 * 1024, "cpu_s": cfg.cpu_s,
                       "fsize_bytes": 16 * 1024 * 1024, "nofile": 256, "core": 0},
            **plan.init,
        }
        deadline = time.monotonic() + cfg.spawn_timeout_s
        try:
            channel.send(init, deadline=deadline)
            msg, _ = channel.recv(deadline)
            if msg.get("op") != "ready":
                raise _ProtocolError(f"expected ready, got {msg.get('op')!r}")
        except (_ChildGone, _Timeout, _ProtocolError) as exc:
            _kill_proc(proc)
            self._owned.proc = None
            why = "timed out" if isinstance(exc, _Timeout) else str(exc) or type(exc).__name__
            raise _SpawnError(f"{why}; {self._stderr_tail() or 'no output'}") from None
        child = _Child(proc, channel, msg, time.perf_counter() - t0)
        self.confinement_layers = {**msg.get("layers", {}), "python": "ok" if self._python_layer else "disabled (test)"}
        self.spawn_s = child.spawn_s
        self.spawns += 1
        return child

    def _stderr_tail(self, n: int = 2000) -> str:
        try:
            with open(os.path.join(self._workdir, "child.stderr"), "rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - n))
                return f.read().decode("utf-8", "replace").strip()
        except OSError:
            return ""

    def _drop_child(self) -> None:
        if self._child is not None:
            self._child.kill()
            self._child = None
            self._owned.proc = None

    # -- running programs
    def run(self, code: str, *, timeout_s: float | None = None) -> dict:
        """Run one program; return the CodeResult payload (already capped to ``result_cap_bytes``).

        ``timeout_s`` lowers the configured timeout for this program only (e.g. to the attempt's
        remaining wall budget). Raises :class:`SandboxUnavailable` if a child cannot be restarted,
        and re-raises whatever ``dispatch`` or ``load_image`` raise (after discarding the child).
        """
        if not isinstance(code, str):
            raise TypeError("run_code code must be a string")
        with self._lock:
            if self._closed:
                raise CabError("the sandbox is closed")
            if self._child is None:
                assert self._plan is not None, "a sandbox that started once has its launch plan"
                try:
                    self._child = self._spawn(self._plan)
                except _SpawnError as exc:
                    raise SandboxUnavailable(f"the run_code sandbox could not be restarted: {exc}") from None
            st = _RunState()
            limit = self.config.timeout_s if timeout_s is None else max(0.0, min(timeout_s, self.config.timeout_s))
            st.limit_s = limit
            t0 = time.monotonic()
            try:
                self._drive(code, st, t0 + limit)
            except BaseException:
                self._drop_child()  # a host fault mid-program: never leave a half-run child behind
                raise
            finally:
                self.last_run_record = {
                    "internal_trace": st.trace_full, "duration_s": round(time.monotonic() - t0, 6),
                    "stdout_chars": (st.done or {}).get("stdout_chars", st.stdout_len),
                    "confinement": self.confinement, "reset_reason": st.reset_reason, "timeout_s": limit,
                    "child_stderr_tail": self._stderr_tail() if st.reset_reason else "",
                }
            return self._result(st)

    def _drive(self, code: str, st: _RunState, deadline: float) -> None:
        child = self._child
        assert child is not None, "run() spawns the child before driving it"
        ch = child.channel
        cfg = self.config
        try:
            ch.send({"op": "run", "code": code}, deadline=deadline)
            while True:
                if time.monotonic() >= deadline:  # also when the program keeps the pipe busy
                    raise _Timeout()
                msg, _ = ch.recv(deadline)
                op = msg["op"]
                if op == "out":
                    self._add_stdout(st, msg.get("text", ""))
                elif op == "call":
                    name, kwargs = msg.get("tool"), msg.get("kwargs")
                    if name not in self.tool_names or not isinstance(kwargs, dict):
                        raise _ProtocolError(f"call to an unbound tool {name!r}")
                    if st.calls >= cfg.max_internal_calls:
                        ch.send({"op": "reply", "stop": "call_cap", "message":
                                 f"internal tool-call limit reached: at most {cfg.max_internal_calls} tool calls "
                                 f"per run_code; the program was stopped before call {st.calls + 1} ({name})"},
                                deadline=deadline)
                        continue
                    index = st.calls
                    st.calls += 1
                    t_call = time.perf_counter()
                    res = self._dispatch(name, kwargs)
                    if not isinstance(res, DispatchResult):
                        raise TypeError(f"dispatch({name!r}) returned {type(res).__name__}, not DispatchResult")
                    self._record_call(st, index, name, kwargs, res, time.perf_counter() - t_call)
                    if res.aborted:
                        st.aborted = (index, name, res.payload)
                        st.ended = bool(res.ended)
                        self._reset(st, "aborted")
                        return
                    if res.ended:
                        st.ended = True
                        ch.send({"op": "reply", "stop": "ended", "message":
                                 "the attempt ended during this program; its remaining tool calls were not run"},
                                deadline=deadline)
                        deadline = min(deadline, time.monotonic() + cfg.stop_grace_s)
                        continue
                    ch.send({"op": "reply", "payload": res.payload}, deadline=deadline)
                elif op == "load_image":
                    self._serve_image(st, ch, msg.get("obs_id"), deadline)
                elif op == "done":
                    st.done = msg
                    return
                else:
                    raise _ProtocolError(f"unexpected {op!r} from the sandbox")
        except _Timeout:
            if st.ended:
                self._reset(st, "ended", "the program did not stop within "
                            f"{cfg.stop_grace_s:g} s after the attempt ended and was killed.")
            else:
                st.timed_out = True
                self._reset(st, "timeout", f"timeout: the program ran longer than {st.limit_s:g} s and was stopped.")
        except _ChildGone:
            if self._closed:
                self._reset(st, "closed", "the sandbox was closed by the host while the program ran.")
                return
            child.proc.poll()
            try:
                child.proc.wait(timeout=2)
            except subprocess.TimeoutExpired:
                pass
            how = child.exit_description()
            self._reset(st, "child_died", f"the sandbox process died ({how}); the memory limit is "
                        f"{cfg.memory_mb} MiB and the CPU limit {cfg.cpu_s} s per sandbox.")
        except _ProtocolError as exc:
            self._reset(st, "protocol_error", f"the sandbox broke protocol ({exc}) and was stopped.")

    def _reset(self, st: _RunState, reason: str, error: str | None = None) -> None:
        self._drop_child()
        st.reset_reason = reason
        if error:
            st.error = error

    def _add_stdout(self, st: _RunState, text: str) -> None:
        room = self.config.stdout_cap - st.stdout_len
        if room > 0 and text:
            st.stdout.append(text[:room])
            st.stdout_len += min(len(text), room)

    def _serve_image(self, st: _RunState, ch: _Channel, obs_id, deadline: float) -> None:
        try:
            if not isinstance(obs_id, str):
                raise ValueError("obs_id must be a string")
            arr = np.asarray(self._load_image(obs_id))
            if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
                raise CabError(f"load_image({obs_id!r}) returned {arr.dtype} {arr.shape}, not HxWx3 uint8")
        except LookupError:  # KeyError included
            ch.send({"op": "image", "error": f"unknown obs_id {obs_id!r}"}, deadline=deadline)
            return
        except (ToolArgumentError, ValueError) as exc:  # the host's own "unknown obs_id" and the like
            ch.send({"op": "image", "error": str(exc)}, deadline=deadline)
            return
        arr = np.ascontiguousarray(arr)
        st.image_events.append(obs_id)
        ch.send({"op": "image", "shape": list(arr.shape)}, blob=arr.data, deadline=deadline)

    def _record_call(self, st: _RunState, index: int, name: str, kwargs: dict, res: DispatchResult,
                     seconds: float) -> None:
        payload = res.payload if isinstance(res.payload, dict) else {"value": res.payload}
        obs = [o for o in (res.obs_ids or []) if isinstance(o, str)]
        for o in obs:
            if o not in st.obs_ids:
                st.obs_ids.append(o)
            st.image_events.append(o)
        failure = payload.get("failure")
        if not isinstance(failure, dict):
            failure = {}
        entry = {
            "index": index, "tool": name, "ok": "error" not in payload,
            "status": payload.get("status"), "action_id": payload.get("action_id"),
            "tick": payload.get("tick"), "abort_reason": payload.get("abort_reason"),
            "failure_category": _pick(payload, "failure_category") or failure.get("category") or failure.get("code"),
            "stop_reason": _pick(payload, "stop_reason"), "transition": _pick(payload, "transition"),
            "obs_ids": obs or None, "error": payload.get("error"),
        }
        entry = {k: v for k, v in entry.items() if v is not None}  # nulls cost bytes under the 32 KiB cap
        st.trace.append(entry)
        full = dict(entry, duration_s=round(seconds, 6), aborted=res.aborted, ended=res.ended)
        args_bytes = json_size(kwargs)
        if args_bytes <= 2000:
            full["args"] = kwargs
        else:
            full["args_omitted"] = True
            full["args_bytes"] = args_bytes
        pose = payload.get("resulting_pose")
        if pose is not None:
            full["achieved_pose"] = pose
        st.trace_full.append(full)

    def _images(self, st: _RunState) -> tuple[list[str], list[str]]:
        """The most recent unique obs_ids by last occurrence (chronological), and the rest."""
        order: list[str] = []
        for o in reversed(st.image_events):
            if o not in order:
                order.append(o)
        order.reverse()
        k = self.config.max_images
        cut = max(0, len(order) - k)
        return order[cut:], order[:cut]

    def _result(self, st: _RunState) -> dict:
        done = st.done or {}
        ok = bool(done.get("ok")) and st.reset_reason is None and not st.ended
        error = st.error if st.error is not None else done.get("error")
        stdout = "".join(st.stdout)
        total = done.get("stdout_chars", st.stdout_len)
        if total > self.config.stdout_cap:
            stdout += f"\n[stdout truncated: {total - self.config.stdout_cap} more characters not shown]"
        elif st.reset_reason and st.stdout_len >= self.config.stdout_cap:
            stdout += "\n[stdout truncated]"
        images, withheld = self._images(st)
        result = {
            "ok": ok, "error": error, "stdout": stdout, "value": done.get("value"),
            "result_assigned": bool(done.get("result_assigned")), "tool_calls": st.calls,
            "obs_ids": st.obs_ids, "internal_trace": st.trace, "filesystem_policy": FILESYSTEM_POLICY,
            "namespace_reset": st.reset_reason is not None, "images": images,
        }
        if withheld:
            result["images_withheld"] = {
                "count": len(withheld), "obs_ids": withheld,
                "note": f"only the {self.config.max_images} most recent images are attached; "
                        "load_image(obs_id) in a later program shows a withheld one"}
        if st.aborted is not None:
            index, name, payload = st.aborted
            reason = payload.get("abort_reason") if isinstance(payload, dict) else None
            result.update(
                status="ABORTED", abort_reason=reason,
                interrupted_action={"index": index, "tool": name, "result": payload},
                failure=payload.get("failure") if isinstance(payload, dict) else None)
            result["error"] = (f"{name} (internal call {index}) returned ABORTED"
                               f"{f' ({reason})' if reason else ''}; the program was stopped there and its "
                               "remaining tool calls were cancelled.")
        if st.ended:
            result["ended"] = True
            if result["error"] is None or done.get("stopped") == "ended":
                result["error"] = error or "the attempt ended during this program; its remaining tool calls were not run"
        if st.timed_out:
            result["timed_out"] = True
        if st.reset_reason is not None:
            result["namespace_reset_reason"] = st.reset_reason
            result["note"] = _RESET_TEXT
            result["error"] = f"{result['error']} {_RESET_TEXT}" if result["error"] else _RESET_TEXT
        found: list[str] = []
        result = finite_json(result, "", found)  # a tool's NaN in the trace: strict JSON for the agent too
        if found:
            result[NON_FINITE_KEY] = non_finite_note(found)
        return cap_result(result, self.config.result_cap_bytes)
