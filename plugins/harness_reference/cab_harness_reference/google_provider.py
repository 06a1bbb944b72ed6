"""The ``google`` provider: Gemini through the official ``google-genai`` SDK (generateContent).

Wire mapping (neutral types.py <-> google.genai.types):

- system prompt -> ``GenerateContentConfig.system_instruction``; ``user`` -> ``Content(role="user")``;
  ``assistant`` -> ``Content(role="model")``; every ``tool`` message -> a ``function_response`` part
  of a ``user`` content (consecutive same-role contents are merged, so all responses to one model
  turn and a follow-up image message travel together).
- ``ToolResult.images`` -> inline image parts *inside* the function response
  (``FunctionResponse.parts``, multimodal function responses) when ``images_in_function_response``
  is true (default), otherwise inline image parts beside it in the same user content.
- ``Thinking``: Gemini's thought summaries (``thought=True``) and its opaque ``thought_signature``
  (bytes, kept base64 in ``Thinking.signature``). A signature that rode on a non-thought part (a
  function call, a text) becomes a ``Thinking(text="")`` placed right before that part and is
  re-attached to it when the conversation is sent back (Gemini 3 requires the signature of
  function calls to be replayed).
- Usage: ``input_tokens`` = prompt + tool-use prompt tokens minus cached tokens (uncached input);
  ``cache_read_tokens`` = ``cached_content_token_count``; ``output_tokens`` = candidates + thoughts
  (everything billed as output); ``reasoning_tokens`` = thoughts (a breakdown of output, counted once).

The SDK's own retries are switched off (``HttpRetryOptions(attempts=1)``); the shared bounded retry
(backoff + jitter) wraps each request and its waiting time is returned as ``Response.waited_s``.
"""
from __future__ import annotations

import base64
import copy
import json
import os
import random
import time
from collections.abc import Callable
from typing import Any

from cab_core.errors import ConfigError, MissingDependency

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

KEY_ENVS = ("GEMINI_API_KEY", "GOOGLE_API_KEY")
_GEN_ID_PREFIX = "gcall_"  # ids we made up for calls the API sent without one (never sent back)

# FACTS A.10: Gemini uses 4 attempts, server-error delays [15, 45, 120] s (here: base 15 s,
# doubling, full jitter, capped), rate-limited from 60 s, timeouts from 2 s.
DEFAULT_RETRY = {"max_attempts": 4, "base_delay_s": {"rate_limit": 60.0, "timeout": 2.0, "server": 15.0},
                 "max_delay_s": 120.0}


# --------------------------------------------------------------------------------------------
# JSON Schema: inline $defs/$ref for Gemini's function declarations
# --------------------------------------------------------------------------------------------
def inline_schema(schema: dict) -> dict:
    """Return a copy of ``schema`` with every local ``$ref`` ("#/$defs/X" or "#/definitions/X")
    replaced by its definition and ``$defs``/``definitions``/``$schema`` removed. Recursive
    references are cut at the second level (replaced by a plain ``{"type": "object"}``)."""
    defs = dict(schema.get("$defs") or {})
    defs.update(schema.get("definitions") or {})

    def resolve(node: Any, stack: tuple) -> Any:
        if isinstance(node, list):
            return [resolve(x, stack) for x in node]
        if not isinstance(node, dict):
            return node
        if "$ref" in node and isinstance(node["$ref"], str):
            ref = node["$ref"]
            name = ref.rsplit("/", 1)[-1]
            if not ref.startswith("#/") or name not in defs:
                raise ConfigError(f"tool schema: unresolvable $ref {ref!r}")
            if name in stack:
                target: Any = {"type": "object"}
            else:
                target = resolve(copy.deepcopy(defs[name]), stack + (name,))
            extra = {k: resolve(v, stack) for k, v in node.items() if k != "$ref"}
            return {**target, **extra}
        out = {}
        for k, v in node.items():
            if k in ("$defs", "definitions", "$schema"):
                continue
            if k == "properties" and isinstance(v, dict):  # property names are not keywords
                out[k] = {pk: resolve(pv, stack) for pk, pv in v.items()}
            else:
                out[k] = resolve(v, stack)
        return out

    return resolve(schema, ())


# --------------------------------------------------------------------------------------------
# the provider
# --------------------------------------------------------------------------------------------
_REFUSAL = {"SAFETY", "RECITATION", "PROHIBITED_CONTENT", "BLOCKLIST", "SPII", "IMAGE_SAFETY",
            "LANGUAGE"}


def _enum_name(v: Any) -> str:
    if v is None:
        return ""
    return str(getattr(v, "name", None) or getattr(v, "value", None) or v)


class GoogleProvider(Provider):
    name = "google"

    def __init__(self, cfg: dict | None = None, *, sleep: Callable[[float], Any] | None = None,
                 rng: random.Random | None = None):
        cfg = dict(cfg or {})
        self.cfg = cfg
        self.model = cfg.get("model_id") or cfg.get("model") or "gemini-3.6-flash"
        env = cfg.get("key_env") or cfg.get("api_key_env")
        self.key_envs: tuple[str, ...] = (env,) if env else KEY_ENVS
        self.key_env = self.key_envs[0]
        self.base_url = cfg.get("base_url") or None
        self.api_version = cfg.get("api_version") or None
        self.max_output_tokens = cfg.get("max_output_tokens", 65536)
        self.reasoning = cfg.get("reasoning", "high")  # disabled/low/medium/high/xhigh or None
        self.thinking_budget = cfg.get("thinking_budget")  # explicit budget wins over the level
        self.include_thoughts = bool(cfg.get("include_thoughts", True))
        self.temperature = cfg.get("temperature")  # FACTS: not sent (null)
        self.timeout_s = float(cfg.get("timeout_s", 600))
        self.images_in_fr = bool(cfg.get("images_in_function_response", True))
        rcfg = {**DEFAULT_RETRY, **(cfg.get("retry") or {})}
        rcfg["base_delay_s"] = {**DEFAULT_RETRY["base_delay_s"], **((cfg.get("retry") or {}).get("base_delay_s") or {})}
        self.retry_policy = RetryPolicy.from_cfg(rcfg, sleep=sleep or time.sleep, rng=rng or random.Random())
        self.capabilities = Capabilities(images_in_tool_results=self.images_in_fr, parallel_tool_calls=True,
                                         prompt_cache=False, reasoning=self.reasoning not in (None, "disabled"),
                                         max_images_per_request=cfg.get("max_images_per_request"))
        self._client = None
        self._gen_ids = 0

    # ---- credentials / client ------------------------------------------------------------
    def _api_key(self) -> str | None:
        for e in self.key_envs:
            v = os.environ.get(e)
            if v:
                return v
        return None

    def check_credentials(self) -> None:
        if not self._api_key():
            names = " or ".join(self.key_envs)
            raise ConfigError(f"google provider: no API key; set {names} in the environment")

    def _sdk(self):
        try:
            from google import genai
            from google.genai import types as gt
        except ImportError as e:  # pragma: no cover
            raise MissingDependency("google-genai", "pip install 'cab-harness-reference[google]'") from e
        return genai, gt

    def client(self):
        if self._client is None:
            self.check_credentials()
            genai, gt = self._sdk()
            ho: dict[str, Any] = {"retry_options": gt.HttpRetryOptions(attempts=1),
                                  "timeout": int(self.timeout_s * 1000)}
            if self.base_url:
                ho["base_url"] = self.base_url
            if self.api_version:
                ho["api_version"] = self.api_version
            self._client = genai.Client(api_key=self._api_key(), http_options=gt.HttpOptions(**ho))
        return self._client

    # ---- neutral -> wire -----------------------------------------------------------------
    def _config(self, system: str, tools: list[ToolSpec]):
        _, gt = self._sdk()
        kw: dict[str, Any] = {}
        if system:
            kw["system_instruction"] = system
        if self.max_output_tokens:
            kw["max_output_tokens"] = int(self.max_output_tokens)
        if self.temperature is not None:
            kw["temperature"] = float(self.temperature)
        if tools:
            kw["tools"] = [gt.Tool(function_declarations=[
                gt.FunctionDeclaration(name=t.name, description=t.description,
                                       parameters_json_schema=inline_schema(t.parameters or {"type": "object"}))
                for t in tools])]
            kw["automatic_function_calling"] = gt.AutomaticFunctionCallingConfig(disable=True)
        tc: dict[str, Any] = {}
        if self.thinking_budget is not None:
            tc["thinking_budget"] = int(self.thinking_budget)
        elif self.reasoning == "disabled":
            tc["thinking_budget"] = 0
        elif self.reasoning:
            level = str(self.reasoning).upper()  # MINIMAL/LOW/MEDIUM/HIGH/XHIGH
            tc["thinking_level"] = level
        if self.include_thoughts and tc.get("thinking_budget") != 0:
            tc["include_thoughts"] = True
        if tc:
            kw["thinking_config"] = gt.ThinkingConfig(**tc)
        return gt.GenerateContentConfig(**kw)

    @staticmethod
    def _wire_id(call_id: str) -> str | None:
        return None if (not call_id or call_id.startswith(_GEN_ID_PREFIX)) else call_id

    def _image_parts(self, img: Image) -> list:
        _, gt = self._sdk()
        out = []
        label = img.label or img.obs_id
        if label:
            out.append(gt.Part(text=f"[image {label}]"))
        out.append(gt.Part(inline_data=gt.Blob(mime_type="image/png", data=img.png)))
        return out

    def _tool_result_parts(self, r: ToolResult) -> list:
        _, gt = self._sdk()
        try:
            payload: Any = json.loads(r.text) if r.text else {}
        except (json.JSONDecodeError, TypeError):
            payload = r.text
        response: dict[str, Any] = {"error" if r.is_error else "output": payload}
        fr_parts = None
        beside: list = []
        if r.images:
            if self.images_in_fr:
                fr_parts, refs = [], []
                for img in r.images:
                    name = f"{img.obs_id or 'image'}.png"
                    fr_parts.append(gt.FunctionResponsePart(inline_data=gt.FunctionResponseBlob(
                        mime_type="image/png", data=img.png, display_name=name)))
                    refs.append({"obs_id": img.obs_id, "label": img.label, "image": {"$ref": name}})
                response["images"] = refs
            else:
                response["images"] = [{"obs_id": i.obs_id, "label": i.label} for i in r.images]
                for img in r.images:
                    beside.extend(self._image_parts(img))
        fr = gt.FunctionResponse(id=self._wire_id(r.call_id), name=r.name, response=response, parts=fr_parts)
        return [gt.Part(function_response=fr)] + beside

    def to_contents(self, messages: list[Message]) -> tuple[str, list]:
        """Neutral messages -> (extra system text, list[Content]). System messages inside the list
        are joined into the system instruction."""
        _, gt = self._sdk()
        system_extra: list[str] = []
        contents: list = []
        for m in messages:
            if m.role == "system":
                system_extra.extend(p.text for p in m.parts if isinstance(p, Text))
                continue
            role = "model" if m.role == "assistant" else "user"
            parts: list = []
            pending_sig: bytes | None = None
            beside: list = []
            for p in m.parts:
                if isinstance(p, Thinking):
                    if p.provider not in ("", "google") or m.role != "assistant":
                        continue  # another provider's reasoning cannot be replayed here
                    sig = base64.b64decode(p.signature) if p.signature else None
                    if p.text:
                        parts.append(gt.Part(text=p.text, thought=True, thought_signature=sig))
                    elif sig:
                        pending_sig = sig
                    continue
                if isinstance(p, Text):
                    if not p.text:
                        continue
                    part = gt.Part(text=p.text)
                elif isinstance(p, ToolCall):
                    args = p.arguments if p.arguments is not None else {"_raw_arguments": p.raw_arguments}
                    part = gt.Part(function_call=gt.FunctionCall(id=self._wire_id(p.call_id), name=p.name, args=args))
                elif isinstance(p, Image):
                    parts.extend(self._image_parts(p))
                    continue
                elif isinstance(p, ToolResult):
                    trp = self._tool_result_parts(p)
                    parts.append(trp[0])
                    beside.extend(trp[1:])
                    continue
                else:  # pragma: no cover
                    continue
                if pending_sig is not None:
                    part.thought_signature = pending_sig
                    pending_sig = None
                parts.append(part)
            parts.extend(beside)  # images beside function responses go after all of them
            if not parts:
                continue
            if contents and contents[-1].role == role:
                prev = contents[-1].parts
                # keep function responses first in a merged user content, images/text after
                if role == "user" and any(getattr(q, "function_response", None) for q in parts):
                    frs = [q for q in parts if q.function_response is not None]
                    rest = [q for q in parts if q.function_response is None]
                    k = max((i + 1 for i, q in enumerate(prev) if q.function_response is not None), default=0)
                    contents[-1].parts = prev[:k] + frs + prev[k:] + rest
                else:
                    contents[-1].parts = prev + parts
            else:
                contents.append(gt.Content(role=role, parts=parts))
        return "\n\n".join(system_extra), contents

    # ---- wire -> neutral -----------------------------------------------------------------
    def _new_id(self) -> str:
        self._gen_ids += 1
        return f"{_GEN_ID_PREFIX}{self._gen_ids:06d}"

    def from_response(self, resp) -> tuple[Message, str, str, Usage]:
        parts: list = []
        cand = (resp.candidates or [None])[0]
        raw = _enum_name(getattr(cand, "finish_reason", None)) if cand is not None else ""
        content = getattr(cand, "content", None)
        for p in (getattr(content, "parts", None) or []):
            sig = base64.b64encode(p.thought_signature).decode("ascii") if p.thought_signature else None
            if p.thought:
                parts.append(Thinking(text=p.text or "", signature=sig, provider="google"))
                continue
            if sig:
                parts.append(Thinking(text="", signature=sig, provider="google"))
            if p.function_call is not None:
                fc = p.function_call
                args = dict(fc.args) if fc.args is not None else {}
                parts.append(ToolCall(call_id=fc.id or self._new_id(), name=fc.name or "",
                                      arguments=args, raw_arguments=json.dumps(args, sort_keys=True)))
            elif p.text:
                parts.append(Text(p.text))
        has_calls = any(isinstance(p, ToolCall) for p in parts)
        if cand is None:
            pf = getattr(resp, "prompt_feedback", None)
            raw = _enum_name(getattr(pf, "block_reason", None)) or "NO_CANDIDATES"
            stop = "refusal"
        elif has_calls:
            stop = "tool_calls"
        elif raw in ("STOP", ""):
            stop = "end_turn"
        elif raw == "MAX_TOKENS":
            stop = "max_tokens"
        elif raw in _REFUSAL:
            stop = "refusal"
        else:
            stop = "other"
        return Message("assistant", parts), stop, raw, self.usage(getattr(resp, "usage_metadata", None))

    @staticmethod
    def usage(um) -> Usage:
        if um is None:
            return Usage()
        prompt = (um.prompt_token_count or 0) + (um.tool_use_prompt_token_count or 0)
        cached = um.cached_content_token_count or 0
        thoughts = um.thoughts_token_count or 0
        return Usage(input_tokens=max(0, prompt - cached), output_tokens=(um.candidates_token_count or 0) + thoughts,
                     reasoning_tokens=thoughts, cache_read_tokens=cached, cache_write_tokens=0)

    # ---- errors --------------------------------------------------------------------------
    @staticmethod
    def classify(e: BaseException) -> ProviderError:
        if isinstance(e, ProviderError):
            return e
        try:
            from google.genai import errors as ge
        except ImportError:  # pragma: no cover
            ge = None
        if ge is not None and isinstance(e, ge.APIError):
            code = int(getattr(e, "code", 0) or 0)
            msg = f"google: {code} {e.status or ''}: {e.message or e}".strip()
            low = (e.message or "").lower()
            if code == 429 and "quota" in low and ("exceeded your current quota" in low or "billing" in low):
                return ProviderError("quota", msg, code)  # the plan's quota: waiting will not help
            if code == 429:
                return ProviderError("rate_limit", msg, code, retryable=True)
            if code in (401, 403) or (code == 400 and "api key not valid" in low):
                return ProviderError("auth", msg, code)
            if code == 402:
                return ProviderError("quota", msg, code)
            if code == 529 or (code == 503 and "overloaded" in low):
                return ProviderError("overloaded", msg, code, retryable=True)
            if code == 408:
                return ProviderError("timeout", msg, code, retryable=True)
            if code == 504:
                return ProviderError("timeout", msg, code, retryable=True)
            if code >= 500:
                return ProviderError("server", msg, code, retryable=True)
            if code == 400 and ("token" in low and ("exceed" in low or "limit" in low or "too long" in low)
                                or "context" in low and "length" in low):
                return ProviderError("context_length", msg, code)
            if 400 <= code < 500:
                return ProviderError("bad_request", msg, code)
            return ProviderError("other", msg, code)
        names = {c.__name__ for c in type(e).__mro__}
        if any("Timeout" in n for n in names) or isinstance(e, TimeoutError):
            return ProviderError("timeout", f"google: {type(e).__name__}: {e}", retryable=True)
        if names & {"ConnectError"} or isinstance(e, ConnectionRefusedError):
            return ProviderError("unreachable", f"google: {type(e).__name__}: {e}", retryable=True,
                                 reason=connection_reason(e))
        if names & {"RemoteProtocolError", "ReadError", "NetworkError", "TransportError"} \
                or isinstance(e, ConnectionError):
            return ProviderError("server", f"google: {type(e).__name__}: {e}", retryable=True)
        return ProviderError("other", f"google: {type(e).__name__}: {e}")

    # ---- one request ---------------------------------------------------------------------
    def complete(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> Response:
        client = self.client()
        extra_system, contents = self.to_contents(messages)
        full_system = "\n\n".join(s for s in (system, extra_system) if s)
        config = self._config(full_system, tools)
        timing = {"latency": 0.0}

        def attempt():
            t0 = time.monotonic()
            try:
                resp = client.models.generate_content(model=self.model, contents=contents, config=config)
            finally:
                timing["latency"] = time.monotonic() - t0
            if not resp.candidates and getattr(resp, "prompt_feedback", None) is None:
                # FACTS A.10: an empty 200 completion is transient
                raise ProviderError("server", "google: empty completion (no candidates)", 200, retryable=True)
            return resp

        try:
            resp, waited = call_with_retries(attempt, self.classify, self.retry_policy)
        except ProviderError as e:  # the line cab prints names the endpoint
            e.at(self.base_url or "https://generativelanguage.googleapis.com")
            raise
        message, stop, raw, usage = self.from_response(resp)
        return Response(message=message, stop_reason=stop, usage=usage,
                        model=getattr(resp, "model_version", None) or self.model,
                        request_id=getattr(resp, "response_id", None), latency_s=timing["latency"],
                        waited_s=waited, raw_stop_reason=raw)


def factory(cfg: dict) -> GoogleProvider:
    return GoogleProvider(cfg)
