"""The conversation an agent had before a fork point, rebuilt from the parent's records, for a
harness that gives its model the same context the parent's model had (the reference harness does).

Reads events only (the dicts of ``events.jsonl``); a harness gets them as ``session.fork.events``
(:class:`cab_core.contracts.harness.ForkOrigin`)."""
from __future__ import annotations

#: the event kinds that are direct calls of the agent, in the order it made them
DIRECT = ("call", "call_refused")

#: the event a harness records when it rebuilds a fork's conversation from its parent's records;
#: its ``model_turns`` give the prefix's turns to :func:`transcript` when this fork is forked again
REBUILT = "conversation_rebuilt"


def transcript(events: list[dict]) -> list[dict]:
    """The conversation an agent had up to the fork point, from the parent's events: turns of
    ``{"text", "calls": [{"call_id", "name", "arguments", "raw_arguments", "result", "obs_ids",
    "status", "made"}]}``, in order.

    A parent played by a reference-harness model gives its model turns with the calls the model
    asked for and their recorded results. ``arguments`` are the model's (None when it sent
    malformed JSON, ``raw_arguments`` then its text: the call itself was made with the harness's
    stand-in). A call cancelled because an earlier action of its turn aborted is kept with ``made``
    False (no result): the model asked for it and was told it was cancelled. The turn of the fork
    point is cut there: the calls the model asked for after it are left out (not the cancelled
    ones: they were cancelled whatever came next).

    The calls no model turn accounts for give one turn each (``call_0001``...): those of a parent
    played by a model-free agent, an MCP client or a script, and the re-executed prefix of a parent
    that was itself a fork, unless its harness recorded the prefix's turns it rebuilt (a
    ``conversation_rebuilt`` event's ``model_turns``): a fork of a fork then has the first parent's
    turns as well."""
    calls = [e for e in events if e.get("kind") in DIRECT]
    prefix = [e for e in calls if e.get("fork_prefix")]
    own = calls[len(prefix):]
    rebuilt = next((e.get("model_turns") for e in events if e.get("kind") == REBUILT), None)
    model = [e for e in events if e.get("kind") == "model_turn"]

    def one_each(made: list[dict], first: int) -> list[dict]:
        return [{"text": "", "tool_calls": [{"call_id": f"call_{first + i + 1:04d}", "name": e.get("tool")}]}
                for i, e in enumerate(made)]  # no "arguments": the call's own are the agent's

    asked = ((rebuilt if prefix and isinstance(rebuilt, list) else one_each(prefix, 0))
             + (model if model else one_each(own, len(prefix))))

    def turn_call(asked_for: dict, e: dict | None) -> dict:
        """One call of a turn: as the model asked for it, with the parent's record of it (``e``;
        None: it was cancelled)."""
        rec = e or {}
        result = rec.get("result") if isinstance(rec.get("result"), dict) else {"result": rec.get("result")}
        return {"call_id": str(asked_for.get("call_id")), "name": str(asked_for.get("name")),
                "arguments": asked_for["arguments"] if "arguments" in asked_for else rec.get("arguments") or {},
                "raw_arguments": asked_for.get("raw_arguments") or "", "result": None if e is None else result,
                "obs_ids": list(rec.get("obs_ids") or []), "status": rec.get("status"), "made": e is not None}

    out: list[dict] = []
    queue, turns = list(calls), iter(asked)
    while queue:
        t = next(turns, None)
        if t is None:  # a call no turn accounts for (records that lack a model turn): none is lost
            t = one_each(queue[:1], len(calls) - len(queue))[0]
        done: list[dict] = []
        aborted = False
        for c in t.get("tool_calls") or []:
            if aborted:  # cancelled, in the parent as in the harness that rebuilds it
                done.append(turn_call(c, None))
            elif queue and queue[0].get("tool") == c.get("name"):
                e = queue.pop(0)
                done.append(turn_call(c, e))
                aborted = e.get("status") == "ABORTED"
            else:  # not made: the fork point (or the attempt's end) came first; nor any after it
                break
        out.append({"text": t.get("text") or "", "calls": done})
    return out
