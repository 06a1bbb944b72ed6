"""The ``openai`` provider: the OpenAI Responses API through the official ``openai`` SDK.

Neutral messages (``types.py``) become Responses input items: user/assistant ``message`` items,
``function_call`` items for assistant tool calls, ``function_call_output`` items for tool results
(images inside the output as ``input_image`` parts), and ``reasoning`` items replayed from the
opaque ``Thinking.signature`` (encrypted reasoning; ``store`` is false). The SDK's own retries are
off (``max_retries=0``); bounded retries with backoff and jitter happen here.

Usage convention (shared with the other adapters): the token buckets do not overlap.
``input_tokens`` is the uncached input (API input minus cache reads and cache writes),
``cache_read_tokens`` / ``cache_write_tokens`` the cached parts; ``output_tokens`` is the API
output total, ``reasoning_tokens`` the part of it spent on reasoning.

Retries use the shared ``retry.call_with_retries`` (config ``retry: {max_attempts, base_delay_s:
{rate_limit, timeout, server}, max_delay_s}``). This module also holds the pieces the
``openai_compatible`` provider shares: the SDK error classification and the client construction.
"""
from __future__ import annotations

import base64
import json
import os
import random
import time
from collections.abc import Callable
from typing import Any

from cab_core.errors import ConfigError, MissingDependency

from .retry import RetryPolicy, call_with_retries, retry_after_s
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

INSTALL = "pip install 'cab-harness-reference[openai]'"

# --- SDK error classification -----------------------------------------------------------------

_CONTEXT_MARKERS = ("context_length_exceeded", "context length", "context window",
                    "maximum context", "too many tokens", "prompt is too long",
                    "input is too long", "reduce the length")


def _err(kind: str, msg: str, status: int | None, retryable: bool,
         exc: BaseException | None = None) -> ProviderError:
    e = ProviderError(kind, msg[:500], status=status, retryable=retryable)
    e.retry_after_s = retry_after_s(exc)
    return e


def classify_openai_error(exc: BaseException) -> ProviderError | None:
    """Map an ``openai`` SDK exception to a ``ProviderError`` kind; ``None`` for exceptions that
    are not provider failures (programming errors propagate)."""
    import openai

    name = type(exc).__name__
    status = getattr(exc, "status_code", None)
    msg = f"{name}: {exc}"
    body = getattr(exc, "body", None)
    code = str(getattr(exc, "code", "") or (body.get("code") if isinstance(body, dict) else "") or "")
    low = (str(exc) + " " + code).lower()
    if isinstance(exc, openai.APITimeoutError):
        e = _err("timeout", msg, None, True, exc)
        e.reason = "no answer within the timeout"
        return e
    if isinstance(exc, openai.APIConnectionError):
        e = _err("unreachable", msg, None, True, exc)
        e.reason = connection_reason(exc)
        return e
    if isinstance(exc, (openai.AuthenticationError, openai.PermissionDeniedError)):
        return _err("auth", msg, status, False, exc)
    if isinstance(exc, openai.RateLimitError):
        if "insufficient_quota" in low or "quota" in code.lower():
            return _err("quota", msg, status, False, exc)  # quota: waiting will not help
        return _err("rate_limit", msg, status, True, exc)
    if status == 402:  # payment required: credit spent
        return _err("quota", msg, status, False, exc)
    if status == 529 or (status is not None and status >= 500 and "overloaded_error" in low):
        return _err("overloaded", msg, status, True, exc)
    if isinstance(exc, openai.InternalServerError):
        return _err("server", msg, status, True, exc)
    if isinstance(exc, openai.APIStatusError):
        if status in (400, 413, 422) and any(m in low for m in _CONTEXT_MARKERS):
            return _err("context_length", msg, status, False, exc)
        if status == 408:
            return _err("timeout", msg, status, True, exc)
        if status in (409, 425) or (status is not None and status >= 500):
            return _err("server", msg, status, True, exc)
        if status == 404:  # no such model or route: the configuration's, not the model's
            e = _err("other", msg, status, False, exc)
            e.reason = "HTTP 404: model or endpoint not found"
            return e
        if status in (400, 413, 422):
            return _err("bad_request", msg, status, False, exc)
        return _err("other", msg, status, False, exc)
    if isinstance(exc, openai.OpenAIError):
        return _err("other", msg, status, False, exc)
    return None


# --- client -----------------------------------------------------------------------------------


def import_openai():
    try:
        import openai  # noqa: F401
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise MissingDependency("the openai SDK", INSTALL) from e
    return openai


def png_data_url(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def image_label(img: Image) -> str:
    return img.label or f"[image {img.obs_id}]"


class _OpenAIBase(Provider):
    """Shared config handling: key variable, base URL, timeouts, retry policy, injectable sleep,
    the output limit and the reasoning effort."""

    default_key_env: str | None = "OPENAI_API_KEY"
    base_url_env: str | None = "OPENAI_BASE_URL"

    def __init__(self, cfg: dict, *, sleep: Callable[[float], None] | None = None,
                 rng: random.Random | None = None):
        self.cfg = dict(cfg or {})
        self.model = str(self.cfg.get("model_id") or self.cfg.get("model") or "")
        if not self.model:
            raise ConfigError(f"model config for provider {self.name!r} has no 'model'")
        if "api_key_env" in self.cfg:
            self.key_env = self.cfg["api_key_env"]  # null: a local server without a key
        elif "key_env" in self.cfg:
            self.key_env = self.cfg["key_env"]
        else:
            self.key_env = self.default_key_env
        self.base_url = self.cfg.get("base_url") or \
            (os.environ.get(self.base_url_env) if self.base_url_env else None) or None
        self.timeout_s = float(self.cfg.get("timeout_s", 600.0))
        self.connect_timeout_s = float(self.cfg.get("connect_timeout_s", 20.0))
        # retry: {max_attempts, base_delay_s: {rate_limit, timeout, server}, max_delay_s}
        self.retry = RetryPolicy.from_cfg(self.cfg.get("retry"), sleep=sleep or time.sleep,
                                          rng=rng or random.Random())
        self.max_output_tokens = self.cfg.get("max_output_tokens")
        self.reasoning_effort = self.cfg.get("reasoning_effort")
        self._client = None

    def check_credentials(self) -> None:
        if self.key_env and not os.environ.get(self.key_env):
            raise ConfigError(f"{self.key_env} is not set: export it with the API key for model "
                              f"{self.model!r} (provider {self.name})")

    def client(self):
        if self._client is None:
            openai = import_openai()
            self.check_credentials()
            key = os.environ.get(self.key_env) if self.key_env else "not-needed"
            self._client = openai.OpenAI(
                api_key=key, base_url=self.base_url, max_retries=0,
                timeout=openai.Timeout(self.timeout_s, connect=self.connect_timeout_s))
        return self._client

    @staticmethod
    def classify(exc: BaseException) -> ProviderError:
        perr = classify_openai_error(exc)
        if perr is None:  # not an SDK error: reported as "other", never retried
            perr = _err("other", f"{type(exc).__name__}: {exc}", None, False)
        return perr

    def _call(self, fn: Callable[[], Any]) -> tuple[Any, float, float]:
        """Run one request with retries; returns (result, latency of the good try, waited_s)."""
        box: dict[str, float] = {}

        def timed():
            t0 = time.monotonic()
            r = fn()
            box["latency"] = time.monotonic() - t0
            return r

        try:
            result, waited = call_with_retries(timed, self.classify, self.retry)
        except ProviderError as e:  # the line cab prints names the endpoint
            e.at(self.endpoint())
            raise
        return result, box.get("latency", 0.0), waited

    def endpoint(self) -> str:
        """The base URL requests go to (the SDK's default when none is configured)."""
        return str(self._client.base_url) if self._client is not None else str(self.base_url or "")

    def request_kwargs(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> dict:
        raise NotImplementedError

    def send(self, client: Any, kw: dict) -> Any:
        """One try of the request ``kw``: the SDK's answer; an empty one raises a retryable
        ``ProviderError`` (an empty 200 completion is transient)."""
        raise NotImplementedError

    def read(self, resp: Any) -> Response:
        """The SDK's answer as a neutral ``Response``."""
        raise NotImplementedError

    def complete(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> Response:
        client = self.client()
        kw = self.request_kwargs(system, messages, tools)
        resp, latency, waited = self._call(lambda: self.send(client, kw))
        out = self.read(resp)
        out.latency_s = latency
        out.waited_s = waited
        return out


def parse_arguments(raw: str) -> dict | None:
    """A tool call's JSON arguments as a dict (``{}`` for none); ``None`` where they are not a JSON
    object, so that the loop answers the model with the error instead of calling the tool."""
    try:
        args = json.loads(raw) if raw.strip() else {}
    except ValueError:
        return None
    return args if isinstance(args, dict) else None


def stop_reason(parts: list, *, refusal: bool, truncated: bool, finished: bool) -> str:
    """The neutral stop reason, in this order: a tool call, a refusal, the output limit, a normal
    end, anything else."""
    if any(isinstance(p, ToolCall) for p in parts):
        return "tool_calls"
    if refusal:
        return "refusal"
    if truncated:
        return "max_tokens"
    if finished:
        return "end_turn"
    return "other"


# --- the Responses provider -------------------------------------------------------------------


def _encode_signature(item_id: str, encrypted: str | None) -> str:
    return json.dumps({"id": item_id, "encrypted_content": encrypted})


def _decode_signature(sig: str | None) -> dict | None:
    if not sig:
        return None
    try:
        d = json.loads(sig)
    except ValueError:
        return None
    return d if isinstance(d, dict) and d.get("id") else None


class OpenAIProvider(_OpenAIBase):
    name = "openai"
    capabilities = Capabilities(images_in_tool_results=True, parallel_tool_calls=True,
                                prompt_cache=True, reasoning=True)

    def __init__(self, cfg: dict, **kw):
        super().__init__(cfg, **kw)
        self.reasoning_summary = self.cfg.get("reasoning_summary", "auto")
        self.cache_breakpoints = bool(self.cfg.get("cache_breakpoints", True))
        self.image_detail = self.cfg.get("image_detail")  # None: the API default

    # neutral -> wire
    def _image_part(self, img: Image) -> dict:
        p: dict[str, Any] = {"type": "input_image", "image_url": png_data_url(img.png)}
        if self.image_detail:
            p["detail"] = self.image_detail
        return p

    def _mark(self, parts: list[dict]) -> None:
        if self.cache_breakpoints and parts:
            parts[-1]["prompt_cache_breakpoint"] = {"mode": "explicit"}

    def to_input(self, messages: list[Message]) -> list[dict]:
        items: list[dict] = []
        for m in messages:
            if m.role == "system":
                continue  # passed as ``instructions``
            if m.role == "user":
                content: list[dict] = []
                for p in m.parts:
                    if isinstance(p, Text):
                        content.append({"type": "input_text", "text": p.text})
                    elif isinstance(p, Image):
                        if p.label:
                            content.append({"type": "input_text", "text": p.label})
                        content.append(self._image_part(p))
                if not content:
                    content.append({"type": "input_text", "text": ""})
                if m.cache_breakpoint:
                    self._mark(content)
                items.append({"type": "message", "role": "user", "content": content})
            elif m.role == "assistant":
                for p in m.parts:
                    if isinstance(p, Thinking):
                        sig = _decode_signature(p.signature) if p.provider in ("", self.name) else None
                        if sig:
                            it: dict[str, Any] = {"type": "reasoning", "id": sig["id"], "summary": (
                                [{"type": "summary_text", "text": p.text}] if p.text else [])}
                            if sig.get("encrypted_content"):
                                it["encrypted_content"] = sig["encrypted_content"]
                            items.append(it)
                    elif isinstance(p, Text):
                        if p.text:
                            items.append({"type": "message", "role": "assistant",
                                          "content": [{"type": "output_text", "text": p.text}]})
                    elif isinstance(p, ToolCall):
                        args = p.raw_arguments or json.dumps(p.arguments or {})
                        items.append({"type": "function_call", "call_id": p.call_id,
                                      "name": p.name, "arguments": args})
            elif m.role == "tool":
                extra_images: list[Image] = [p for p in m.parts if isinstance(p, Image)]
                results = [p for p in m.parts if isinstance(p, ToolResult)]
                for i, r in enumerate(results):
                    imgs = list(r.images) + (extra_images if i == len(results) - 1 else [])
                    if imgs or (m.cache_breakpoint and self.cache_breakpoints):
                        out: Any = [{"type": "input_text", "text": r.text}]
                        for img in imgs:
                            out.append({"type": "input_text", "text": image_label(img)})
                            out.append(self._image_part(img))
                        if m.cache_breakpoint:
                            self._mark(out)
                    else:
                        out = r.text
                    items.append({"type": "function_call_output", "call_id": r.call_id,
                                  "output": out})
        return items

    def to_tools(self, tools: list[ToolSpec]) -> list[dict]:
        return [{"type": "function", "name": t.name, "description": t.description,
                 "parameters": t.parameters, "strict": False} for t in tools]

    def request_kwargs(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> dict:
        kw: dict[str, Any] = {"model": self.model, "input": self.to_input(messages),
                              "store": False, "include": ["reasoning.encrypted_content"]}
        if system:
            kw["instructions"] = system
        if tools:
            kw["tools"] = self.to_tools(tools)
        if self.reasoning_effort:
            r: dict[str, Any] = {"effort": self.reasoning_effort}
            if self.reasoning_summary:
                r["summary"] = self.reasoning_summary
            kw["reasoning"] = r
        if self.max_output_tokens:
            kw["max_output_tokens"] = int(self.max_output_tokens)
        if self.cfg.get("extra_body"):
            kw["extra_body"] = dict(self.cfg["extra_body"])
        return kw

    # wire -> neutral
    def from_response(self, resp) -> Response:
        parts: list = []
        refusal = False
        for item in resp.output or []:
            t = getattr(item, "type", None)
            if t == "reasoning":
                text = "\n".join(s.text for s in (item.summary or []))
                if not text and getattr(item, "content", None):
                    text = "\n".join(c.text for c in item.content)
                parts.append(Thinking(text=text, provider=self.name, signature=_encode_signature(
                    item.id, getattr(item, "encrypted_content", None))))
            elif t == "message":
                for c in item.content or []:
                    ct = getattr(c, "type", None)
                    if ct == "output_text":
                        parts.append(Text(c.text))
                    elif ct == "refusal":
                        refusal = True
                        parts.append(Text(c.refusal))
            elif t == "function_call":
                raw = item.arguments or ""
                parts.append(ToolCall(call_id=item.call_id, name=item.name, arguments=parse_arguments(raw),
                                      raw_arguments=raw))
        status = getattr(resp, "status", None) or ""
        reason = getattr(getattr(resp, "incomplete_details", None), "reason", None) or ""
        stop = stop_reason(parts, refusal=refusal or reason == "content_filter",
                           truncated=reason == "max_output_tokens", finished=status == "completed")
        return Response(message=Message("assistant", parts), stop_reason=stop,
                        usage=usage_from_responses(getattr(resp, "usage", None)),
                        model=getattr(resp, "model", "") or self.model,
                        request_id=getattr(resp, "_request_id", None),
                        raw_stop_reason=reason or status)

    def send(self, client: Any, kw: dict) -> Any:
        r = client.responses.create(**kw)
        if not (r.output or []):
            raise _err("server", "empty response output", 200, True)
        return r

    def read(self, resp: Any) -> Response:
        return self.from_response(resp)


def _i(v) -> int:
    try:
        return int(v or 0)
    except (TypeError, ValueError):
        return 0


def usage_from_responses(u) -> Usage:
    if u is None:
        return Usage()
    itd = getattr(u, "input_tokens_details", None)
    otd = getattr(u, "output_tokens_details", None)
    cached = _i(getattr(itd, "cached_tokens", 0))
    written = _i(getattr(itd, "cache_write_tokens", 0))
    total_in = _i(getattr(u, "input_tokens", 0))
    return Usage(input_tokens=max(0, total_in - cached - written),
                 output_tokens=_i(getattr(u, "output_tokens", 0)),
                 reasoning_tokens=_i(getattr(otd, "reasoning_tokens", 0)),
                 cache_read_tokens=cached, cache_write_tokens=written)


def factory(cfg: dict) -> OpenAIProvider:
    return OpenAIProvider(cfg)
