"""The ``human`` agent (``model=human``): a person plays an attempt from cab-studio's play page.

The attempt runs through the normal runner (:func:`cab_core.attempt.runner.run_attempt`) under the
core's ``direct`` harness, in a thread of the studio that owns the simulator, planner and records
(as any attempt's single owner thread). The person's calls come over HTTP; the studio's request
handlers never touch the attempt: each call becomes a :class:`Job` on the FIFO of a
:class:`PlayBridge` (the same hand-over as the MCP harness's call bridge), the owner thread executes
it with ``episode.call`` and hands back what a model would get: the payload, the images the result
carries (:func:`cab_core.attempt.agent_io.result_images`, at most ``max_images_per_result``) and
the budgets left. The page shows the prompt every harness gives (:meth:`PlayBridge.prompt`: the
system prompt and the task instruction of :mod:`cab_core.attempt.agent_io`) and nothing privileged:
no verdict until the attempt has ended and ``result.json`` is written.

The records are those of any attempt (the same event kinds, the same verifier); ``result.json``
``model`` is ``human`` (the config's name) and its ``agent`` block names the person
(:mod:`cab_core.attempt.agent_record`: kind ``human``, the handle as the client's name).

The agent finds its bridge by ``model.session`` in this process's :data:`SESSIONS` (the studio
registers one before it starts the attempt); from the command line (``cab model=human``) there is
none, and the attempt is refused before any simulator starts.
"""
from __future__ import annotations

import concurrent.futures as cf
import queue
import secrets
import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from cab_core.attempt.agent_io import (continuation_note, first_user_message, result_images, run_code_limits,
                                       system_prompt)
from cab_core.attempt.agent_record import AgentRecord, ClientInfo
from cab_core.errors import AttemptEnded, ConfigError

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
    """One call waiting for the owner thread."""
    name: str
    arguments: dict[str, Any]
    future: cf.Future = field(default_factory=cf.Future)


class PlayBridge:
    """FIFO of a person's calls from the studio's request handlers to the attempt's owner thread,
    and what the page may show of the attempt (published by the owner once the world is built)."""

    def __init__(self, handle: str) -> None:
        self.handle = handle
        self.id = secrets.token_hex(8)
        self._jobs: queue.Queue[Job] = queue.Queue()
        self._lock = threading.Lock()
        self.ready = threading.Event()  # set once the prompt and tools are published
        self.closed = threading.Event()  # set once the attempt has ended (no more calls)
        self._abandon: tuple[str, str] | None = None
        self.info: dict = {}  # system prompt, instruction, tools, budgets (see :meth:`publish`)
        self.budget: dict = {}
        self.calls = 0

    # -- studio side --------------------------------------------------------------------------
    def submit(self, name: str, arguments: dict[str, Any] | None) -> cf.Future:
        """Queue a call; its future resolves to an :class:`Answer`. Raises AttemptEnded once the
        attempt has ended."""
        if self.closed.is_set():
            raise AttemptEnded("the attempt has ended")
        job = Job(str(name), dict(arguments or {}))
        self._jobs.put(job)
        return job.future

    def abandon(self, reason: str, detail: str) -> None:
        """End the attempt from the studio's side (it is stopping, or the person left)."""
        with self._lock:
            self._abandon = self._abandon or (reason, detail)

    # -- owner side ---------------------------------------------------------------------------
    def publish(self, episode: AttemptSession) -> None:
        spec = episode.spec
        self.budget = dict(episode.ledger.remaining())
        self.info = {
            "system_prompt": system_prompt(self.budget, run_code=run_code_limits(spec)),
            "instruction": first_user_message(episode.instruction) + continuation_note(getattr(spec, "fork", None)),
            "tools": episode.tool_specs(),
            "task": spec.task, "seed": spec.seed, "sim": spec.sim, "attempt": spec.attempt,
        }
        self.ready.set()

    def next(self, timeout: float) -> Job | None:
        try:
            return self._jobs.get(timeout=timeout)
        except queue.Empty:
            return None

    def abandoned(self) -> tuple[str, str] | None:
        with self._lock:
            return self._abandon

    def close(self) -> None:
        """No more calls: answer every queued one with "the attempt has ended"."""
        self.closed.set()
        while True:
            job = self.next(0)
            if job is None:
                return
            job.future.set_result(Answer(job.name, {"error": "the attempt has ended", "attempt_ended": True},
                                         budget=self.budget, ended=True))


#: the bridges of the play sessions of this process, by id (``model.session``)
SESSIONS: dict[str, PlayBridge] = {}


def register(bridge: PlayBridge) -> str:
    SESSIONS[bridge.id] = bridge
    return bridge.id


class HumanAgent:
    """A person, through a :class:`PlayBridge`: executes the calls the studio queues, one at a
    time in arrival order, until the attempt ends (``done``, a spent budget, the studio stopping).
    Ends the attempt and writes ``result.json`` before it answers the call that ended it, so the
    page can show the result at once."""

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
                job.future.set_result(self._execute(episode, job))
        finally:
            bridge.budget = dict(episode.ledger.remaining())
            bridge.close()

    def _execute(self, episode: AttemptSession, job: Job) -> Answer:
        try:
            r = episode.call(job.name, job.arguments)
        except AttemptEnded as e:
            return Answer(job.name, {"error": str(e), "attempt_ended": True}, budget=self.bridge.budget, ended=True)
        except BaseException as e:  # never leave the page waiting on a future
            job.future.set_result(Answer(job.name, {"error": f"internal error: {e!r}", "attempt_ended": True},
                                         ended=True))
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

