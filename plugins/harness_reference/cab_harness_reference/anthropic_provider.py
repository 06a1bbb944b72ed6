"""Anthropic Messages API through the official ``anthropic`` SDK (FACTS A.10 "Provider adapters").

Images go inside ``tool_result`` blocks; messages the context policy marks get a
``cache_control`` breakpoint (plus the system prompt); thinking (adaptive or budgeted) and effort
come from the model config; usage maps cache-read/-write tokens. The SDK's own retries are off
(``max_retries=0``): ``retry.py`` retries, and its waiting time is reported.

Model config keys: ``model_id`` (API model name), ``max_output_tokens``, ``thinking`` (dict sent
as is, e.g. ``{type: adaptive}`` or ``{type: enabled, budget_tokens: 32000}``), ``effort``
(``output_config.effort``), ``base_url`` (else ``ANTHROPIC_BASE_URL``), ``api_key_env``
(default ``ANTHROPIC_API_KEY``), ``timeout_s`` (hard, default 600), ``connect_timeout_s``
(default 20), ``retry`` (see ``RetryPolicy.from_cfg``)."""
from __future__ import annotations

import base64
import json
import os
import time
from typing import Any

from cab_core.errors import ConfigError

from .retry import RetryPolicy, call_with_retries
from .types import (
    Capabilities,
    Image,
    Message,
    Provider,
    ProviderError,
    Response,
    Text,
    Thinking,
    ToolCall,
    ToolResult,
    ToolSpec,
    Usage,
    connection_reason,
)

MAX_CACHE_BREAKPOINTS = 4
_STOP = {"tool_use": "tool_calls", "end_turn": "end_turn", "stop_sequence": "end_turn", "max_tokens": "max_tokens",
         "refusal": "refusal", "model_context_window_exceeded": "max_tokens"}
_CONTEXT_HINTS = ("prompt is too long", "context length", "context window", "too many tokens", "maximum context")


def classify(e: BaseException) -> ProviderError:
    """SDK exception -> ProviderError kind (retry.py decides on retries by kind)."""
    import anthropic

    msg = str(e)[:2000]
    if isinstance(e, ProviderError):
        return e
    if isinstance(e, anthropic.APITimeoutError):
        return ProviderError("timeout", msg, reason="no answer within the timeout")
    if isinstance(e, anthropic.APIConnectionError):
        return ProviderError("unreachable", f"connection error: {msg}", reason=connection_reason(e))
    if isinstance(e, anthropic.APIStatusError):
        s = int(e.status_code)
        low = msg.lower()
        body = e.body if isinstance(e.body, dict) else {}
        err = body.get("error") if isinstance(body.get("error"), dict) else body
        etype = str(err.get("type") or "")
        if s in (401, 403):
            return ProviderError("auth", msg, s)
        if s == 402 or etype == "billing_error" or "credit balance" in low:
            return ProviderError("quota", msg, s)  # credit spent: waiting will not help
        if s == 429:
            return ProviderError("rate_limit", msg, s)
        if s == 408:
            return ProviderError("timeout", msg, s)
        if s == 413 or (s == 400 and any(h in low for h in _CONTEXT_HINTS)):
            return ProviderError("context_length", msg, s)
        if s == 529 or etype == "overloaded_error":
            return ProviderError("overloaded", msg, s)
        if s >= 500 or s == 409:
            return ProviderError("server", msg, s)
        if s == 404:  # no such model: the configuration's, not the model's
            return ProviderError("other", msg, s, reason="HTTP 404: model or endpoint not found")
        return ProviderError("bad_request", msg, s)
    return ProviderError("other", f"{type(e).__name__}: {msg}")


def _image_block(img: Image) -> dict:
    return {"type": "image", "source": {"type": "base64", "media_type": "image/png",
                                        "data": base64.b64encode(img.png).decode("ascii")}}


def to_wire(messages: list[Message]) -> list[dict]:
    """Neutral messages -> Messages API ``messages`` (tool results become user turns; consecutive
    turns of one role are merged; thinking from other providers is dropped)."""
    out: list[dict] = []
    marks: list[int] = []  # indices into out whose last block gets cache_control
    for m in messages:
        if m.role == "system":
            continue
        role = "assistant" if m.role == "assistant" else "user"
        blocks: list[dict] = []
        for p in m.parts:
            if isinstance(p, Text):
                if p.text:
                    blocks.append({"type": "text", "text": p.text})
            elif isinstance(p, Image):
                blocks.append(_image_block(p))
            elif isinstance(p, ToolCall) and role == "assistant":
                blocks.append({"type": "tool_use", "id": p.call_id, "name": p.name,
                               "input": p.arguments if isinstance(p.arguments, dict) else {}})
            elif isinstance(p, ToolResult):
                content: list[dict] = [{"type": "text", "text": p.text or "(empty)"}]
                content += [_image_block(i) for i in p.images]
                blocks.append({"type": "tool_result", "tool_use_id": p.call_id, "content": content,
                               **({"is_error": True} if p.is_error else {})})
            elif isinstance(p, Thinking) and role == "assistant" and p.provider.startswith("anthropic"):
                if p.provider == "anthropic-redacted":
                    blocks.append({"type": "redacted_thinking", "data": p.signature or ""})
                elif p.signature:
                    blocks.append({"type": "thinking", "thinking": p.text, "signature": p.signature})
        if not blocks:
            blocks = [{"type": "text", "text": "(no content)"}]
        if out and out[-1]["role"] == role:
            if role == "user":  # tool_result blocks must lead the user turn
                merged = out[-1]["content"] + blocks
                merged.sort(key=lambda b: 0 if b["type"] == "tool_result" else 1)
                out[-1]["content"] = merged
            else:
                out[-1]["content"] += blocks
        else:
            out.append({"role": role, "content": blocks})
        if m.cache_breakpoint:
            marks.append(len(out) - 1)
    for i in sorted(set(marks))[-(MAX_CACHE_BREAKPOINTS - 1):]:
        out[i]["content"][-1]["cache_control"] = {"type": "ephemeral"}
    return out


def from_wire(resp: Any) -> tuple[Message, str, Usage]:
    parts: list = []
    for b in resp.content or []:
        t = getattr(b, "type", None)
        if t == "text":
            parts.append(Text(b.text))
        elif t == "thinking":
            parts.append(Thinking(b.thinking, getattr(b, "signature", None), "anthropic"))
        elif t == "redacted_thinking":
            parts.append(Thinking("", getattr(b, "data", None), "anthropic-redacted"))
        elif t == "tool_use":
            args = b.input if isinstance(b.input, dict) else None
            parts.append(ToolCall(b.id, b.name, args, raw_arguments=json.dumps(b.input, default=str)))
    u = resp.usage
    usage = Usage(input_tokens=int(getattr(u, "input_tokens", 0) or 0),
                  output_tokens=int(getattr(u, "output_tokens", 0) or 0),
                  cache_read_tokens=int(getattr(u, "cache_read_input_tokens", 0) or 0),
                  cache_write_tokens=int(getattr(u, "cache_creation_input_tokens", 0) or 0))
    return Message("assistant", parts), str(resp.stop_reason or ""), usage


class AnthropicProvider(Provider):
    name = "anthropic"
    capabilities = Capabilities(images_in_tool_results=True, parallel_tool_calls=True, prompt_cache=True,
                                reasoning=True)

    def __init__(self, cfg: dict):
        self.cfg = dict(cfg or {})
        self.key_env = str(self.cfg.get("api_key_env") or "ANTHROPIC_API_KEY")
        self.model = str(self.cfg.get("model_id") or self.cfg.get("name") or "")
        self.max_tokens = int(self.cfg.get("max_output_tokens") or 8192)
        self.retry_policy = RetryPolicy.from_cfg(self.cfg.get("retry"))
        self._client = None

    def check_credentials(self) -> None:
        if not os.environ.get(self.key_env):
            raise ConfigError(f"{self.key_env} is not set: model {self.cfg.get('name', self.model)!r} "
                              f"(provider anthropic) needs it in the environment")
        if not self.model:
            raise ConfigError("the anthropic provider needs model.model_id")

    @property
    def client(self):
        if self._client is None:
            import anthropic

            self.check_credentials()
            self._timeout = anthropic.Timeout(float(self.cfg.get("timeout_s") or 600.0),
                                          connect=float(self.cfg.get("connect_timeout_s") or 20.0))
            self._client = anthropic.Anthropic(
                api_key=os.environ[self.key_env],
                base_url=self.cfg.get("base_url") or os.environ.get("ANTHROPIC_BASE_URL") or None,
                max_retries=0, timeout=self._timeout)
        return self._client

    def request_params(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> dict:
        params: dict = {
            "model": self.model,
            "max_tokens": self.max_tokens,
            "system": [{"type": "text", "text": system, "cache_control": {"type": "ephemeral"}}],
            "messages": to_wire(messages),
            "tools": [{"name": t.name, "description": t.description, "input_schema": t.parameters} for t in tools],
        }
        if self.cfg.get("thinking"):
            params["thinking"] = dict(self.cfg["thinking"])
        if self.cfg.get("effort"):
            params["output_config"] = {"effort": str(self.cfg["effort"])}
        return params

    def complete(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> Response:
        params = self.request_params(system, messages, tools)
        client = self.client
        t_last = [0.0]

        def once():
            t0 = time.monotonic()
            try:
                # an explicit timeout: no streaming (FACTS A.10), and no SDK refusal of long non-streamed requests
                r = client.messages.create(**params, timeout=self._timeout)
            finally:
                t_last[0] = time.monotonic() - t0
            if not r.content and r.stop_reason not in ("end_turn", "refusal"):  # empty 200: transient
                raise ProviderError("server", f"empty completion (stop_reason={r.stop_reason})", 200)
            return r

        try:
            r, waited = call_with_retries(once, classify, self.retry_policy)
        except ProviderError as e:  # the line cab prints names the endpoint
            e.at(client.base_url)
            raise
        msg, raw_stop, usage = from_wire(r)
        return Response(msg, _STOP.get(raw_stop, "other"), usage, model=str(getattr(r, "model", "") or self.model),
                        request_id=getattr(r, "_request_id", None) or getattr(r, "id", None),
                        latency_s=t_last[0], waited_s=waited, raw_stop_reason=raw_stop)


def factory(cfg: dict) -> AnthropicProvider:
    return AnthropicProvider(cfg)
