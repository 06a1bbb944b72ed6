"""Provider-neutral conversation types. Adapters convert these to and from each provider's wire
format; the loop and the context policy only ever see these.

A conversation is a list of ``Message``. Roles: ``system`` (one, first), ``user``, ``assistant``,
``tool`` (one per tool result, answering an assistant ``ToolCall`` by ``call_id``). Content parts:
``Text``, ``Image`` (PNG bytes + the observation id it shows), ``ToolCall`` (assistant only),
``ToolResult`` (tool role only; may hold images for providers that accept them in tool results),
``Thinking`` (assistant reasoning kept for providers that need it replayed, opaque ``signature``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from cab_core.kits.harness.pricing import Usage  # noqa: F401  (a Response's usage; providers import it from here)

Role = Literal["system", "user", "assistant", "tool"]


@dataclass
class Text:
    text: str


@dataclass
class Image:
    png: bytes
    obs_id: str
    label: str = ""  # e.g. "obs_0003 head_camera tick 4"


@dataclass
class ToolCall:
    call_id: str
    name: str
    arguments: dict[str, Any] | None  # None when the model sent malformed JSON
    raw_arguments: str = ""
    salvaged: bool = False  # recovered by the harness from a server's unparsed output (probe.salvage_calls)


@dataclass
class ToolResult:
    call_id: str
    name: str
    text: str  # the JSON payload as text
    images: list[Image] = field(default_factory=list)
    is_error: bool = False


@dataclass
class Thinking:
    text: str
    signature: str | None = None  # provider's opaque replay token (Anthropic signature, OpenAI encrypted content)
    provider: str = ""


Part = Text | Image | ToolCall | ToolResult | Thinking


@dataclass
class Message:
    role: Role
    parts: list[Part]
    cache_breakpoint: bool = False  # the context policy marks where a prompt cache may end


@dataclass
class ToolSpec:
    name: str
    description: str
    parameters: dict  # JSON Schema


@dataclass
class Response:
    """One model response: its message (assistant role), why it stopped, usage and timings."""
    message: Message
    stop_reason: Literal["tool_calls", "end_turn", "max_tokens", "refusal", "other"]
    usage: Usage
    model: str = ""
    request_id: str | None = None
    latency_s: float = 0.0
    waited_s: float = 0.0  # time spent in retries/backoff (provider outage, not charged to wall)
    raw_stop_reason: str = ""


@dataclass(frozen=True)
class Capabilities:
    """What a provider accepts; the harness adapts messages to these."""
    images_in_tool_results: bool
    parallel_tool_calls: bool = True
    prompt_cache: bool = False
    reasoning: bool = False
    max_images_per_request: int | None = None


#: What a failed request was, and whose: every kind but the model's own (``bad_request``,
#: ``context_length``) is the infrastructure's, and an attempt that ends on one is never scored.
#: Each with the words and the hint of the one line ``cab`` prints for it.
PROVIDER_ERROR_KINDS = {
    "unreachable": ("provider unreachable", "is the server running, and is model.base_url right?"),
    "timeout": ("provider timed out", "the provider did not answer in time (model.timeout_s); try again later"),
    "rate_limit": ("provider rate limit", "lower the request rate (or concurrency) or try again later"),
    "quota": ("provider quota exhausted", "the account's quota or credit is spent: add credit or raise the limit"),
    "auth": ("provider refused the credentials", "check the API key in the environment and its permissions"),
    "server": ("provider server error", "the provider failed; try again later"),
    "overloaded": ("provider overloaded", "the provider is overloaded; try again later"),
    "bad_request": ("provider rejected the request", "the request was refused as malformed"),
    "context_length": ("context length exceeded", "the conversation outgrew the model's context"),
    "other": ("provider failure", "see the attempt's events.jsonl (provider_failure)"),
}
MODEL_KINDS = frozenset({"bad_request", "context_length"})  # the model's (or its request's) own: scored


class ProviderError(Exception):
    """A provider failure after retries. ``kind``: one of :data:`PROVIDER_ERROR_KINDS` (unreachable,
    timeout, rate_limit, quota, auth, server, overloaded: the infrastructure's; bad_request,
    context_length: the model's own; other). ``url``: the endpoint (base URL) the request went to;
    ``reason``: a few words on the cause (``connection refused``, ``HTTP 529``).
    ``retry_after_s``: the server's ``Retry-After``, where it sent one (every worker sharing the
    credential waits for it)."""

    def __init__(self, kind: str, message: str, status: int | None = None, retryable: bool = False,
                 retry_after_s: float | None = None, url: str | None = None, reason: str | None = None):
        super().__init__(message)
        self.kind = kind
        self.status = status
        self.retryable = retryable
        self.retry_after_s = retry_after_s
        self.url = url
        self.reason = reason

    @property
    def infrastructure(self) -> bool:
        """Whether the failure is the infrastructure's (the attempt is not scored), not the model's."""
        return self.kind not in MODEL_KINDS

    def at(self, url: object) -> ProviderError:
        """This error with the endpoint it happened at (kept when already known); returns itself."""
        if self.url is None and url:
            self.url = str(url).rstrip("/")
        return self

    def summary(self) -> str:
        """One line: what failed, where, why, and a hint (``provider unreachable at
        http://127.0.0.1:9/v1 (connection refused): is the server running, ...?``)."""
        what, hint = PROVIDER_ERROR_KINDS.get(self.kind, PROVIDER_ERROR_KINDS["other"])
        why = self.reason or (f"HTTP {self.status}" if self.status else None) or " ".join(str(self).split())[:160]
        where = f" at {self.url}" if self.url else ""
        return f"{what}{where} ({why}): {hint}"


def connection_reason(exc: BaseException) -> str:
    """A few words on why a connection failed, from the exception's chain: ``connection refused``,
    ``name not resolved`` (DNS), ``connection reset``, else the innermost exception's type."""
    import socket

    seen: list[BaseException] = []
    e: BaseException | None = exc
    while e is not None and e not in seen and len(seen) < 10:
        seen.append(e)
        e = e.__cause__ or e.__context__
    for x in seen:
        if isinstance(x, ConnectionRefusedError):
            return "connection refused"
        if isinstance(x, socket.gaierror):
            return "name not resolved"
        if isinstance(x, ConnectionResetError):
            return "connection reset"
    for x in seen:  # httpx words it without the OSError (e.g. "[Errno 111] Connection refused")
        low = str(x).lower()
        if "connection refused" in low:
            return "connection refused"
        if "name or service not known" in low or "nodename nor servname" in low or "name resolution" in low:
            return "name not resolved"
    return type(seen[-1]).__name__


class Provider:
    """The contract of a provider adapter (one per API). ``factory(cfg)`` builds it from the model
    config; it must check its API key in ``check_credentials`` without any network call and raise
    ``cab_core.errors.ConfigError`` naming the environment variable when missing."""

    name: str = "abstract"
    capabilities: Capabilities = Capabilities(images_in_tool_results=False)
    key_env: str | None = None

    def check_credentials(self) -> None:
        raise NotImplementedError

    def complete(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> Response:
        """One request with bounded retries (backoff + jitter on rate limits, timeouts and server
        errors); raises ProviderError when retries are exhausted."""
        raise NotImplementedError
