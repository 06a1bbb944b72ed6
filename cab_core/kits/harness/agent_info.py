"""Who played an attempt: the optional ``agent`` block of ``result.json``.

The configuration an attempt belongs to is its ``model`` (with harness and simulator); the
``agent`` block says what actually played it when the harness can tell more than the config:
an attempt served over MCP (``harness=mcp`` and the vendor launchers built on it) records every
client that identified itself in the MCP ``initialize`` handshake (``clientInfo``)::

    "agent": {
      "kind": "mcp_client",
      "named_by": "config",            # where "model" came from: config | client | placeholder
      "client": {"name": "claude-code", "version": "2.1.212", "session": 1},
      "clients": [{"name": "claude-code", "version": "2.1.212", "session": 1}]
    }

``client`` is the first client identified (the one an unnamed configuration is named after),
``clients`` every distinct identity in the order first seen; ``session`` numbers the MCP sessions
(one per stdio server; over HTTP each connecting client gets its own), so two clients of the same
name and version in two sessions are two entries, and a session whose client identifies itself
anew under another name or version adds one. ``client`` is null when no client identified itself.

A harness talking to a model API may add ``serving``: the endpoint that served the model, the
serving engine and version where the server says (vLLM, llama.cpp, Ollama) and the capability
profile its probe found (``kind: "model_api"``, ``client`` null)::

    "agent": {"kind": "model_api", "named_by": "config", "client": null, "clients": [],
              "serving": {"engine": "vllm", "version": "0.11.2", "base_url": "...", "model_id": "...",
                          "profile": {...}}}

Records without the block (other harnesses, records written before it existed) are valid.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from cab_core.errors import RecordError

NAMED_BY = ("config", "client", "placeholder")


@dataclass(frozen=True)
class ClientInfo:
    """One MCP client's identity from its handshake, and the MCP session it came in."""
    name: str
    version: str
    session: int = 1

    @property
    def label(self) -> str:
        return f"{self.name}/{self.version}"

    def as_dict(self) -> dict:
        return {"name": self.name, "version": self.version, "session": self.session}

    @classmethod
    def from_dict(cls, d, where: str = "agent.client") -> ClientInfo:
        if not isinstance(d, dict):
            raise RecordError(f"result.json {where} should be an object, got {type(d).__name__}")
        for k in ("name", "version"):
            if not isinstance(d.get(k), str):
                raise RecordError(f"result.json {where}.{k} should be a string, got {d.get(k)!r}")
        s = d.get("session", 1)
        if not isinstance(s, int) or isinstance(s, bool) or s < 1:
            raise RecordError(f"result.json {where}.session should be a positive integer, got {s!r}")
        return cls(d["name"], d["version"], s)


@dataclass
class AgentRecord:
    """The ``agent`` block of ``result.json``."""
    kind: str
    named_by: str
    client: ClientInfo | None = None
    clients: list[ClientInfo] = field(default_factory=list)
    serving: dict | None = None  # the serving endpoint, engine and capability profile (model APIs)

    def as_dict(self) -> dict:
        out = {"kind": self.kind, "named_by": self.named_by,
               "client": self.client.as_dict() if self.client else None,
               "clients": [c.as_dict() for c in self.clients]}
        if self.serving is not None:
            out["serving"] = self.serving
        return out

    @classmethod
    def from_dict(cls, d) -> AgentRecord:
        """The block as written; RecordError naming the first field of the wrong shape."""
        if not isinstance(d, dict):
            raise RecordError(f"result.json 'agent' should be an object, got {type(d).__name__}")
        if not isinstance(d.get("kind"), str):
            raise RecordError(f"result.json agent.kind should be a string, got {d.get('kind')!r}")
        if d.get("named_by") not in NAMED_BY:
            raise RecordError(f"result.json agent.named_by should be one of {list(NAMED_BY)}, got {d.get('named_by')!r}")
        clients = d.get("clients", [])
        if not isinstance(clients, list):
            raise RecordError(f"result.json agent.clients should be a list, got {type(clients).__name__}")
        client = d.get("client")
        serving = d.get("serving")
        if serving is not None and not isinstance(serving, dict):
            raise RecordError(f"result.json agent.serving should be an object, got {type(serving).__name__}")
        return cls(d["kind"], d["named_by"], None if client is None else ClientInfo.from_dict(client),
                   [ClientInfo.from_dict(c, f"agent.clients[{i}]") for i, c in enumerate(clients)], serving)

    @classmethod
    def of_result(cls, result: dict) -> AgentRecord | None:
        """The block of a ``result.json``, None when it has none."""
        return None if result.get("agent") is None else cls.from_dict(result["agent"])
