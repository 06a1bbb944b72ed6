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


class ProviderError(Exception):
    """A provider failure after retries (not the model's fault). ``kind``: auth, rate_limit,
    timeout, server, bad_request, context_length, other."""

    def __init__(self, kind: str, message: str, status: int | None = None, retryable: bool = False):
        super().__init__(message)
        self.kind = kind
        self.status = status
        self.retryable = retryable


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
