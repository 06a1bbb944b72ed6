"""The ``openai_compatible`` provider: Chat Completions through the official ``openai`` SDK, for
Qwen (DashScope), Kimi (Moonshot), Grok (xAI) and local servers (vLLM, Ollama, llama.cpp).

Tool results go back as ``tool`` messages holding text only; images (this API does not accept them
in tool messages, ``capabilities.images_in_tool_results`` is False) go into one follow-up ``user``
message appended after all tool messages of that assistant turn, each preceded by its label.
Reasoning text the server returns (``reasoning_content``, or ``reasoning``) becomes ``Thinking``
and is replayed as ``reasoning_content`` on assistant messages (thinking preservation, needed by
Qwen and Kimi); ``replay_reasoning: false`` turns that off for servers that reject the field.

Config keys: ``model``, ``base_url`` (required unless ``OPENAI_BASE_URL`` is set),
``api_key_env`` (default ``OPENAI_API_KEY``; ``null`` for a local server without a key),
``max_output_tokens``, ``max_tokens_param`` (``max_tokens`` or ``max_completion_tokens``),
``reasoning_effort``, ``extra_body`` (provider-specific fields, e.g. ``enable_thinking``),
``cache_control`` (DashScope-style explicit cache markers on cache breakpoints), ``retry``.
Usage follows the convention in ``openai_provider``: non-overlapping token buckets.
"""
from __future__ import annotations

import json
from typing import Any

from .openai_provider import _err, _i, _OpenAIBase, image_label, parse_arguments, png_data_url, stop_reason
from .types import Capabilities, Image, Message, Response, Text, Thinking, ToolCall, ToolResult, ToolSpec, Usage


class OpenAICompatibleProvider(_OpenAIBase):
    name = "openai_compatible"
    capabilities = Capabilities(images_in_tool_results=False, parallel_tool_calls=True,
                                prompt_cache=False, reasoning=True)

    def __init__(self, cfg: dict, **kw):
        super().__init__(cfg, **kw)
        self.max_tokens_param = self.cfg.get("max_tokens_param", "max_tokens")
        self.replay_reasoning = bool(self.cfg.get("replay_reasoning", True))
        self.cache_control = bool(self.cfg.get("cache_control", False))

    # neutral -> wire
    @staticmethod
    def _image_parts(img: Image) -> list[dict]:
        return [{"type": "text", "text": image_label(img)},
                {"type": "image_url", "image_url": {"url": png_data_url(img.png)}}]

    def _mark(self, content: list[dict]) -> None:
        if self.cache_control and content:
            content[-1]["cache_control"] = {"type": "ephemeral"}

    def to_messages(self, system: str, messages: list[Message]) -> list[dict]:
        out: list[dict] = []
        if system:
            out.append({"role": "system", "content": system})
        pending: list[Image] = []  # images from the current run of tool messages

        def flush():
            if pending:
                content: list[dict] = []
                for img in pending:
                    content.extend(self._image_parts(img))
                out.append({"role": "user", "content": content})
                pending.clear()

        for m in messages:
            if m.role != "tool":
                flush()
            if m.role == "system":
                continue
            if m.role == "user":
                content: list[dict] = []
                for p in m.parts:
                    if isinstance(p, Text):
                        content.append({"type": "text", "text": p.text})
                    elif isinstance(p, Image):
                        content.extend(self._image_parts(p))
                if m.cache_breakpoint:
                    self._mark(content)
                if all(c["type"] == "text" and "cache_control" not in c for c in content):
                    out.append({"role": "user", "content": "\n".join(c["text"] for c in content)})
                else:
                    out.append({"role": "user", "content": content})
            elif m.role == "assistant":
                texts = [p.text for p in m.parts if isinstance(p, Text) and p.text]
                calls = [p for p in m.parts if isinstance(p, ToolCall)]
                thinking = [p.text for p in m.parts if isinstance(p, Thinking) and p.text]
                msg: dict[str, Any] = {"role": "assistant",
                                       "content": "\n".join(texts) if texts else None}
                if calls:
                    msg["tool_calls"] = [{
                        "id": c.call_id, "type": "function",
                        "function": {"name": c.name,
                                     "arguments": c.raw_arguments or json.dumps(c.arguments or {})}}
                        for c in calls]
                if thinking and self.replay_reasoning:
                    msg["reasoning_content"] = "\n".join(thinking)
                if msg["content"] is None and not calls:
                    msg["content"] = ""
                out.append(msg)
            elif m.role == "tool":
                for p in m.parts:
                    if isinstance(p, ToolResult):
                        out.append({"role": "tool", "tool_call_id": p.call_id, "content": p.text})
                        pending.extend(p.images)
                    elif isinstance(p, Image):
                        pending.append(p)
        flush()
        return out

    def to_tools(self, tools: list[ToolSpec]) -> list[dict]:
        return [{"type": "function", "function": {"name": t.name, "description": t.description,
                                                  "parameters": t.parameters}} for t in tools]

    def request_kwargs(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> dict:
        kw: dict[str, Any] = {"model": self.model, "messages": self.to_messages(system, messages)}
        if tools:
            kw["tools"] = self.to_tools(tools)
        if self.max_output_tokens:
            kw[self.max_tokens_param] = int(self.max_output_tokens)
        if self.reasoning_effort:
            kw["reasoning_effort"] = self.reasoning_effort
        if self.cfg.get("extra_body"):
            kw["extra_body"] = dict(self.cfg["extra_body"])
        return kw

    # wire -> neutral
    def from_completion(self, resp) -> Response:
        choice = resp.choices[0]
        msg = choice.message
        parts: list = []
        extra = getattr(msg, "model_extra", None) or {}
        reasoning = extra.get("reasoning_content") or extra.get("reasoning")
        if isinstance(reasoning, str) and reasoning:
            parts.append(Thinking(text=reasoning, provider=self.name))
        if msg.content:
            parts.append(Text(msg.content))
        refusal = bool(getattr(msg, "refusal", None))
        if refusal:
            parts.append(Text(msg.refusal))
        for tc in msg.tool_calls or []:
            fn = getattr(tc, "function", None)
            if fn is None:
                continue
            raw = fn.arguments or ""
            parts.append(ToolCall(call_id=tc.id, name=fn.name, arguments=parse_arguments(raw), raw_arguments=raw))
        fr = choice.finish_reason or ""
        stop = stop_reason(parts, refusal=refusal or fr == "content_filter", truncated=fr == "length",
                           finished=fr == "stop")
        return Response(message=Message("assistant", parts), stop_reason=stop,
                        usage=usage_from_chat(getattr(resp, "usage", None)),
                        model=getattr(resp, "model", "") or self.model,
                        request_id=getattr(resp, "_request_id", None) or getattr(resp, "id", None),
                        raw_stop_reason=fr)

    def send(self, client: Any, kw: dict) -> Any:
        r = client.chat.completions.create(**kw)
        if not r.choices:
            raise _err("server", "empty completion (no choices)", 200, True)
        m = r.choices[0].message
        if not (m.content or m.tool_calls or getattr(m, "refusal", None)) and \
                r.choices[0].finish_reason not in ("length", "content_filter"):
            raise _err("server", "empty completion (no content, no tool calls)", 200, True)
        return r

    def read(self, resp: Any) -> Response:
        return self.from_completion(resp)


def usage_from_chat(u) -> Usage:
    if u is None:
        return Usage()
    ptd = getattr(u, "prompt_tokens_details", None)
    ctd = getattr(u, "completion_tokens_details", None)
    extra = getattr(u, "model_extra", None) or {}
    pextra = getattr(ptd, "model_extra", None) or {}
    cached = _i(getattr(ptd, "cached_tokens", 0)) or _i(extra.get("cached_tokens"))  # Kimi: top level
    written = _i(pextra.get("cache_creation_input_tokens"))  # DashScope explicit cache
    total_in = _i(getattr(u, "prompt_tokens", 0))
    return Usage(input_tokens=max(0, total_in - cached - written),
                 output_tokens=_i(getattr(u, "completion_tokens", 0)),
                 reasoning_tokens=_i(getattr(ctd, "reasoning_tokens", 0)),
                 cache_read_tokens=cached, cache_write_tokens=written)


def factory(cfg: dict) -> OpenAICompatibleProvider:
    return OpenAICompatibleProvider(cfg)
