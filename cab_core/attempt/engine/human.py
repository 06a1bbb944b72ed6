"""The ``human`` agent (``model=human``): a person plays an attempt from cab-studio's play page.

The attempt runs through the normal runner (:func:`cab_core.attempt.runner.run_attempt`) under the
core's ``direct`` harness, in a child process of the studio of its own
(:mod:`cab_core.apps.studio.child`, started by :mod:`cab_core.apps.studio.play`) that owns the
simulator, planner and records, so that a simulator's crash ends that attempt only. The person's
calls come over HTTP; the studio's request handlers never touch the attempt: each call is sent by
the studio's :class:`PlayBridge` to the play's process over a
:class:`multiprocessing.connection.Connection` (one end of a socket pair; the messages are those
named below :class:`Job`), where :class:`HumanAgent`, the attempt's owner, reads them from its
:class:`ChildBridge` in arrival order, executes each with ``episode.call`` and sends back what a
model would get: the payload, the images the result carries
(:func:`cab_core.kits.harness.prompts.result_images`, at most ``max_images_per_result``, as PNG bytes)
and the budgets left; a thread of the studio per play reads the answers and resolves each call's
future. The page shows the prompt every harness gives (:meth:`ChildBridge.publish`: the system
prompt and the task instruction of :mod:`cab_core.kits.harness.prompts`) and nothing privileged: no
verdict until the attempt has ended and ``result.json`` is written. If the play's process dies
before the attempt ended, every call waiting and every later one is answered that it ended
unexpectedly (:func:`crash_error`, ``attempt_ended``).

The records are those of any attempt (the same event kinds, the same verifier); ``result.json``
``model`` is ``human`` (the config's name) and its ``agent`` block names the person
(:mod:`cab_core.kits.harness.agent_info`: kind ``human``, the handle as the client's name).

The agent finds its bridge by ``model.session`` in its process's :data:`SESSIONS`, which only the
studio's play process fills (before it starts the attempt); from the command line
(``cab model=human``) there is none, and the attempt is refused before any simulator starts.
"""
from __future__ import annotations

import concurrent.futures as cf
import secrets
import signal
import threading
from dataclasses import asdict, dataclass, field
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

from cab_core.errors import AttemptEnded, ConfigError
from cab_core.kits.harness.agent_info import AgentRecord, ClientInfo
from cab_core.kits.harness.prompts import (
    continuation_note,
    first_user_message,
    result_images,
    run_code_limits,
    system_prompt,
)
from cab_core.tools.motion import HARNESS_PARAMETERS

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.harness import AttemptSession

AGENT_KIND = "human"
CLIENT_VERSION = "cab-studio"  # the "version" of the person's identity in the agent block


@dataclass
class Answer:
    """What the person gets back from one call: what a model gets (payload, images), the budgets
    left, whether the attempt has ended."""
    tool: str
    payload: dict
    images: list[tuple[str, bytes]] = field(default_factory=list)  # (obs_id, PNG), as a model is shown them
    withheld: list[str] = field(default_factory=list)
    budget: dict = field(default_factory=dict)
    ended: bool = False


@dataclass
class Job:
    """One call the studio handed to the attempt's process (``id``: the studio's number for it)."""
    id: int
    name: str
    arguments: dict[str, Any]


# the messages between the studio (parent) and the process of one play (child): dicts, ``kind`` one of
CALL = "call"  # studio -> play: {"id", "name", "arguments"}
ABANDON = "abandon"  # studio -> play: {"reason", "detail"}: end the attempt (the studio stops)
READY = "ready"  # play -> studio: {"info", "budget"}: the world is built, the prompt and tools published
ANSWER = "answer"  # play -> studio: {"id", "answer": Answer as a dict, "calls", "budget"}
CLOSED = "closed"  # play -> studio: {"budget"}: the attempt has ended, no more calls are executed
FAILED = "failed"  # play -> studio: {"error"}: the attempt's run raised (sent before the process exits)

ENDED = "the attempt has ended"


def ended_answer(name: str, error: str, budget: dict | None = None) -> Answer:
    return Answer(name, {"error": error, "attempt_ended": True}, budget=dict(budget or {}), ended=True)


def crash_error(code: int | None) -> str:
    """What the calls of a play whose process died get: its exit status, and the signal that killed it."""
    how = f"exit code {code}"
    if code is not None and code < 0:
        try:
            how += f", killed by {signal.Signals(-code).name}"
        except ValueError:
            pass
    return f"the simulator process ended unexpectedly ({how}); {ENDED}, its records stop where the process died"


class PlayBridge:
    """The studio's side of one play: the person's calls, sent to the play's process in arrival order
    over ``conn`` (a :class:`multiprocessing.connection.Connection`), each answered by a future, and
    what the page may show of the attempt (published by that process once the world is built).
    :meth:`serve`, in a thread of the studio, reads what the process sends until it ends."""

    def __init__(self, handle: str) -> None:
        self.handle = handle
        self.id = secrets.token_hex(8)
        self._conn: Connection | None = None
        self._lock = threading.Lock()  # the pending calls and the state below
        self._sending = threading.Lock()  # the connection's sending end (never held with the other: the
        # reader thread, which resolves the answers, never waits on a send blocked by a full socket)
        self._pending: dict[int, tuple[str, cf.Future]] = {}  # by call id, in the order sent
        self._next_id = 1
        self._abandon: tuple[str, str] | None = None
        self.ready = threading.Event()  # set once the prompt and tools are published
        self.closed = threading.Event()  # set once the attempt has ended (no more calls)
        self.error: str | None = None  # why the calls answer as they do once the process died (crash_error)
        self.failure: str | None = None  # the exception the attempt's run raised, as the process reported it
        self.info: dict = {}  # system prompt, instruction, tools, budgets (see :meth:`ChildBridge.publish`)
        self.budget: dict = {}
        self.calls = 0

    def attach(self, conn: Connection) -> None:
        """The studio's end of the connection to the play's process (before any call is submitted)."""
        with self._sending:
            self._conn = conn
        with self._lock:
            gone = self._abandon
        if gone is not None:
            self._send({"kind": ABANDON, "reason": gone[0], "detail": gone[1]})

    def _send(self, message: dict) -> None:
        with self._sending:
            try:
                if self._conn is not None:
                    self._conn.send(message)
            except (OSError, ValueError):  # the process is gone: serve() ends, and the play says why
                pass

    # -- the request handlers ------------------------------------------------------------------
    def submit(self, name: str, arguments: dict[str, Any] | None) -> cf.Future:
        """Send a call; its future resolves to an :class:`Answer`. Raises AttemptEnded once the
        attempt has ended; once its process died, the answer says so (:func:`crash_error`)."""
        future: cf.Future = cf.Future()
        with self._lock:
            if self.error is not None:
                future.set_result(ended_answer(str(name), self.error, self.budget))
                return future
            if self.closed.is_set():
                raise AttemptEnded(ENDED)
            call_id, self._next_id = self._next_id, self._next_id + 1
            self._pending[call_id] = (str(name), future)
        self._send({"kind": CALL, "id": call_id, "name": str(name), "arguments": dict(arguments or {})})
        return future

    def abandon(self, reason: str, detail: str) -> None:
        """End the attempt from the studio's side (it is stopping, or the person left)."""
        with self._lock:
            if self._abandon is not None:
                return
            self._abandon = (reason, detail)
        self._send({"kind": ABANDON, "reason": reason, "detail": detail})

    # -- the studio's reader thread --------------------------------------------------------------
    def serve(self) -> None:
        """Read what the play's process sends until its end of the connection closes (it exited,
        or died). Then :meth:`fail` or :meth:`close` says what the calls still waiting get."""
        conn = self._conn
        assert conn is not None, "attach() first"
        while True:
            try:
                m = conn.recv()
            except (EOFError, OSError):
                return
            kind = m.get("kind")
            if kind == READY:
                self.info, self.budget = m["info"], m["budget"]
                self.ready.set()
            elif kind == ANSWER:
                with self._lock:
                    self.calls, self.budget = m["calls"], m["budget"]
                    _, future = self._pending.pop(m["id"], (None, None))
                if future is not None:
                    future.set_result(Answer(**m["answer"]))
            elif kind == CLOSED:
                self.budget = m["budget"]
                self.close()
            elif kind == FAILED:
                self.failure = m["error"]

    def close(self) -> None:
        """No more calls: the calls still waiting, and any later one, are answered "the attempt has
        ended" (or raise AttemptEnded)."""
        self._end(ENDED)

    def fail(self, error: str) -> None:
        """The play's process died before the attempt ended: the calls still waiting, and every
        later one, are answered ``error``."""
        with self._lock:
            if not self.closed.is_set():
                self.error = error
        self._end(error)

    def _end(self, error: str) -> None:
        with self._lock:
            self.closed.set()
            pending, self._pending = self._pending, {}
        for name, future in pending.values():
            future.set_result(ended_answer(name, error, self.budget))

    def disconnect(self) -> None:
        with self._sending:
            if self._conn is not None:
                self._conn.close()


class ChildBridge:
    """The attempt's side of a play, in the play's process: the calls the studio sends, read one at
    a time by :class:`HumanAgent` (the attempt's owner), and what it sends back."""

    def __init__(self, conn: Connection, session: str, handle: str) -> None:
        self.conn = conn
        self.id = session
        self.handle = handle
        self._abandon: tuple[str, str] | None = None
        self.budget: dict = {}
        self.calls = 0

    def _send(self, message: dict) -> None:
        try:
            self.conn.send(message)
        except OSError:  # the studio is gone: this process is killed with it (PR_SET_PDEATHSIG)
            self._abandon = self._abandon or ("interrupted", "cab-studio went away while the attempt was played")

    def publish(self, episode: AttemptSession) -> None:
        spec = episode.spec
        self.budget = dict(episode.ledger.remaining())
        info = {
            "system_prompt": system_prompt(self.budget, HARNESS_PARAMETERS, run_code=run_code_limits(spec)),
            "instruction": first_user_message(episode.instruction) + continuation_note(getattr(spec, "fork", None)),
            "tools": episode.tool_specs(),
            "task": spec.task, "seed": spec.seed, "sim": spec.sim, "attempt": spec.attempt,
        }
        self._send({"kind": READY, "info": info, "budget": self.budget})

    def next(self, timeout: float) -> Job | None:
        """The next call, or None when none came within ``timeout`` s (an abandon read meanwhile is
        then in :meth:`abandoned`)."""
        try:
            if self._abandon is not None or not self.conn.poll(timeout):
                return None
            m = self.conn.recv()
        except (EOFError, OSError):
            self._abandon = self._abandon or ("interrupted", "cab-studio went away while the attempt was played")
            return None
        if m.get("kind") == ABANDON:
            self._abandon = self._abandon or (m["reason"], m["detail"])
            return None
        return Job(int(m["id"]), str(m["name"]), dict(m.get("arguments") or {}))

    def abandoned(self) -> tuple[str, str] | None:
        return self._abandon

    def answer(self, job: Job, answer: Answer) -> None:
        self._send({"kind": ANSWER, "id": job.id, "answer": asdict(answer), "calls": self.calls,
                    "budget": self.budget})

    def close(self) -> None:
        """No more calls (the studio answers those it sent meanwhile "the attempt has ended")."""
        self._send({"kind": CLOSED, "budget": self.budget})

    def failed(self, error: str) -> None:
        self._send({"kind": FAILED, "error": error})


#: the bridge of the play this process runs, by session id (``model.session``): set only by the
#: studio's play process (:mod:`cab_core.apps.studio.child`)
SESSIONS: dict[str, ChildBridge] = {}


class HumanAgent:
    """A person, through a :class:`ChildBridge`: executes the calls the studio sends, one at a
    time in arrival order, until the attempt ends (``done``, a spent budget, the studio stopping).
    Ends the attempt and writes ``result.json`` before it answers the call that ended it, so the
    page can show the result at once."""

    config_keys = frozenset({"handle", "session", "max_images_per_result"})  # of its model configuration

    def __init__(self, cfg: dict):
        self.cfg = cfg
        session = cfg.get("session")
        if not session or session not in SESSIONS:
            raise ConfigError("model=human is played by a person from cab-studio's play page "
                              "(cab-studio <dir>, then 'Play an attempt'); it cannot run from the command line")
        self.bridge = SESSIONS[session]
        handle = str(cfg.get("handle") or self.bridge.handle or "").strip()
        if not handle:
            raise ConfigError("model=human needs the person's name or handle (model.handle)")
        self.handle = handle
        self.max_images = int(cfg.get("max_images_per_result") or 6)

    def run(self, episode: AttemptSession) -> None:
        bridge = self.bridge
        person = ClientInfo(self.handle, CLIENT_VERSION, 1)
        episode.agent = AgentRecord(AGENT_KIND, "config", person, [person]).as_dict()
        bridge.publish(episode)
        try:
            while not episode.ended:
                job = bridge.next(timeout=0.1)
                if job is None:
                    gone = bridge.abandoned()
                    if gone is not None:
                        episode.end(*gone)
                    elif episode.ledger.exhausted_reason() == "wall_budget":
                        episode.end("wall_budget", "wall-clock budget spent while waiting for the person")
                    continue
                bridge.answer(job, self._execute(episode, job))
        finally:
            bridge.budget = dict(episode.ledger.remaining())
            bridge.close()

    def _execute(self, episode: AttemptSession, job: Job) -> Answer:
        try:
            r = episode.call(job.name, job.arguments)
        except AttemptEnded as e:
            return ended_answer(job.name, str(e), self.bridge.budget)
        except BaseException as e:  # never leave the page waiting on an answer
            self.bridge.answer(job, ended_answer(job.name, f"internal error: {e!r}"))
            raise
        shown, withheld = result_images(episode, r.obs_ids, self.max_images)
        payload = dict(r.payload)
        if withheld:
            payload.setdefault("images_not_attached", withheld)
        self.bridge.calls += 1
        self.bridge.budget = dict(episode.ledger.remaining())
        if episode.ended:
            episode.finish()  # result.json before the answer: the page goes on to the result
        return Answer(job.name, payload, shown, withheld, dict(self.bridge.budget), episode.ended)

