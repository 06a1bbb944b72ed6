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

A local server's quirks (:mod:`.probe`) are handled here: :meth:`apply_profile` takes the
endpoint's capability profile (images in ``tool`` messages when the server accepts them, the
server's cap on images per request), and a response whose tool calls the server's parser left in
``content`` (``<tool_call>{...}</tool_call>`` or bare JSON), or whose arguments lost their closing
brace, has them salvaged as real calls marked ``salvaged``.
"""
from __future__ import annotations

import dataclasses
import json
from typing import Any

from .openai_provider import _err, _i, _OpenAIBase, image_label, parse_arguments, png_data_url, stop_reason
from .probe import repair_json, salvage_calls
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
        self.profile: dict | None = None  # the endpoint's capability profile, once applied
        self._tool_names: set[str] = set()
        self._salvaged = 0
        self.tools_in_prompt = False
        self._tool_prompt = ""

    def apply_profile(self, profile: dict) -> None:
        """Adapt to what the endpoint was found to accept (:func:`.probe.probe_endpoint`): images
        go in tool messages only where the server took one there, and no request carries more
        images than the server's cap."""
        self.profile = profile
        if not profile.get("reachable", True):
            return
        # a server that refuses ``tools`` (llama-server without --jinja): the tools are described
        # in the system prompt and the calls read from the text
        self.tools_in_prompt = profile.get("tools") == "rejected"
        cap = profile.get("max_images_per_request")
        self.capabilities = dataclasses.replace(
            type(self).capabilities, images_in_tool_results=profile.get("images_in_tool_results") is True,
            max_images_per_request=int(cap) if isinstance(cap, int) else None)

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
        if self.tools_in_prompt and self._tool_prompt:
            out[0:1] = [{"role": "system", "content": ((system + "\n\n") if system else "") + self._tool_prompt}]
        pending: list[Image] = []  # images from the current run of tool messages
        pending_text: list[str] = []  # tool results as text (tools described in the prompt)

        def flush():
            if pending or pending_text:
                content: list[dict] = [{"type": "text", "text": t} for t in pending_text]
                for img in pending:
                    content.extend(self._image_parts(img))
                if pending:
                    out.append({"role": "user", "content": content})
                else:
                    out.append({"role": "user", "content": "\n".join(pending_text)})
                pending.clear()
                pending_text.clear()

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
                if calls and self.tools_in_prompt:
                    msg["content"] = "\n".join(texts + [TOOL_CALL_FORMAT.format(json.dumps(
                        {"name": c.name, "arguments": c.arguments if c.arguments is not None else c.raw_arguments}))
                        for c in calls])
                elif calls:
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
            elif m.role == "tool" and self.tools_in_prompt:
                for p in m.parts:  # results go back in one user message, as text, images after them
                    if isinstance(p, ToolResult):
                        pending_text.append(f"<tool_response>\n{json.dumps({'name': p.name, 'result': p.text})}"
                                            "\n</tool_response>")
                        pending.extend(p.images)
                    elif isinstance(p, Image):
                        pending.append(p)
            elif m.role == "tool":
                for p in m.parts:
                    if isinstance(p, ToolResult) and p.images and self.capabilities.images_in_tool_results:
                        parts: list[dict] = [{"type": "text", "text": p.text}]
                        for img in p.images:
                            parts.extend(self._image_parts(img))
                        out.append({"role": "tool", "tool_call_id": p.call_id, "content": parts})
                    elif isinstance(p, ToolResult):
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
        self._tool_names = {t.name for t in tools}
        self._tool_prompt = tool_prompt(tools) if self.tools_in_prompt and tools else ""
        kw: dict[str, Any] = {"model": self.model, "messages": self.to_messages(system, messages)}
        if tools and not self.tools_in_prompt:
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
        content = msg.content or ""
        salvaged: list[ToolCall] = []
        if content and not msg.tool_calls:  # the server's parser left the calls in the text
            found, content = salvage_calls(content, self._tool_names or None)
            for name, args in found:
                self._salvaged += 1
                salvaged.append(ToolCall(call_id=f"salvaged_{self._salvaged}", name=name, arguments=args,
                                         raw_arguments=json.dumps(args), salvaged=True))
        if content:
            parts.append(Text(content))
        refusal = bool(getattr(msg, "refusal", None))
        if refusal:
            parts.append(Text(msg.refusal))
        calls = [tc for tc in msg.tool_calls or [] if getattr(tc, "function", None) is not None]
        for tc in calls:
            raw = tc.function.arguments or ""
            args = parse_arguments(raw)
            fixed = repair_json(raw) if args is None and len(calls) == 1 else None
            if isinstance(fixed, dict):  # a parser that lost the closing brace: repaired, one call only
                parts.append(ToolCall(call_id=tc.id, name=tc.function.name, arguments=fixed,
                                      raw_arguments=json.dumps(fixed), salvaged=True))
            else:
                parts.append(ToolCall(call_id=tc.id, name=tc.function.name, arguments=args, raw_arguments=raw))
        parts += salvaged
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


TOOL_CALL_FORMAT = "<tool_call>\n{}\n</tool_call>"


def tool_prompt(tools: list[ToolSpec]) -> str:
    """The tools described in the system prompt, for a server that refuses ``tools`` (the
    Hermes convention the open models are trained on: ``<tool_call>`` blocks in the text)."""
    specs = "\n".join(json.dumps({"name": t.name, "description": t.description, "parameters": t.parameters})
                      for t in tools)
    return ("# Tools\n\nYou may call one or more of these tools (JSON Schemas):\n<tools>\n" + specs +
            "\n</tools>\n\nFor each call, write a JSON object with the tool's name and arguments in "
            "<tool_call></tool_call> tags:\n" + TOOL_CALL_FORMAT.format('{"name": <name>, "arguments": <object>}') +
            "\nThe results come back in <tool_response></tool_response> tags.")


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
