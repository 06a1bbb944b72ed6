"""The ``inspect`` provider: the reference harness on Inspect AI's model API, so the paper's loop,
context policy, image rule and run_code limits run on any model Inspect can call
(``cab model=inspect model.model_id=<provider>/<model>``: ``anthropic/claude-...``,
``openai/gpt-...``, ``google/gemini-...``, ``bedrock/...``, ``vllm/...``, ``ollama/...``,
``openai-api/<service>/<model>`` for any OpenAI-compatible server, ``mockllm/model``).

**The conversion** (also what an Inspect agent running the reference loop calls):

- :func:`to_inspect` ``(system, messages, tools, images_in_tool_results=False)`` turns a cab
  request into Inspect's ``(list[ChatMessage], list[ToolInfo])``: the system prompt as a
  ``ChatMessageSystem``; a user message as a ``ChatMessageUser`` (its text joined into one string,
  or, with images, ``ContentText`` parts and each image as its label followed by a
  ``ContentImage`` PNG data URL); an assistant message as a ``ChatMessageAssistant`` (text joined,
  ``ContentReasoning`` for replayed thinking, ``ToolCall`` per call); a tool result as a
  ``ChatMessageTool`` (the JSON payload as text, and its images where the provider takes them in
  tool messages). Tool schemas have their ``$defs``/``$ref`` inlined and become ``ToolParams``.
- :func:`from_output` ``(ModelOutput)`` turns Inspect's answer into a cab :class:`Response`: text,
  thinking, tool calls (arguments ``None`` where Inspect could not parse them), the stop reason,
  usage (Inspect's and cab's token buckets agree: uncached input, cache reads and writes apart,
  output including reasoning) and the request's time. A ``model_length`` stop (Inspect's word for a
  request over the context window) raises ``ProviderError("context_length")``, the model's own, so
  the loop compacts once as it does on any provider.

Images are laid out as the ``openai_compatible`` provider lays them out, so that one scripted model
behind one OpenAI-compatible server gets the same messages from both (tests/test_inspect_provider.py
compares the two at the wire). Where the Inspect provider takes images in tool messages
(``ModelAPI.tool_result_images()``, e.g. Anthropic), ``capabilities.images_in_tool_results`` is
true and the loop keeps them there; otherwise the loop moves them into a user message after the
tool messages, as for every provider of cab (``model.images_in_tool_results`` forces either).

**Calls.** The attempt is synchronous, Inspect is async: each thread that calls :meth:`complete`
gets its own event loop (an ``asyncio.Runner``) and its own Inspect ``Model`` (built in that loop,
``memoize=False``), reused for every turn; :meth:`close` (the harness calls it after the attempt,
and a finalizer at the latest) closes the models' clients and the loops.

**Retries** happen inside Inspect (``GenerateConfig.max_retries`` = ``model.retry.max_attempts - 1``,
``attempt_timeout`` = ``model.timeout_s``), after the provider SDK's own (the OpenAI and Anthropic
SDKs retry twice by default, honouring ``Retry-After``; ``model.model_args.max_retries: 0`` turns
those off). The wait between Inspect's tries is cab's: the server's ``Retry-After`` where it sent
one (which also pauses every worker sharing the credential under ``model.limits``), else the
backoff of ``model.retry`` (full jitter, ``base_delay_s`` per kind); what cab never retries (a spent
quota, refused credentials) Inspect does not retry either. When the retries are spent the
error that escapes (tenacity's ``RetryError`` around the SDK's exception, Inspect's
``ModelGenerateError`` around a refused request, ``AttemptTimeoutError``) is mapped to cab's
:data:`~.types.PROVIDER_ERROR_KINDS` by the SDK's own classifier (OpenAI, Anthropic, Google), else
by HTTP status and connection errors: unreachable, timeout, rate_limit, quota, auth, server,
overloaded are the infrastructure's (the attempt ends ``provider_failure``, never scored);
bad_request and context_length are the model's.

**Credentials.** :meth:`check_credentials` builds the Inspect model without any network call:
Inspect's provider raises its ``PrerequisiteError`` naming the environment variables it reads
(``OPENAI_API_KEY``, ``<SERVICE>_API_KEY`` and ``<SERVICE>_BASE_URL`` for ``openai-api/<service>/...``),
which becomes cab's one-line ``ConfigError``; ``key_envs`` are the variables Inspect's provider
declares (``ModelAPI.api_key_vars``). ``model.api_key_env`` names a variable whose value is
passed as the key instead.

Config keys: ``model_id`` (the Inspect model string, required), ``base_url``, ``api_key_env``,
``model_args`` (Inspect's ``-M`` model arguments; for ``mockllm/model`` a string
``custom_outputs`` is read as a JSON file of ``ModelOutput`` objects, the scripted outputs tests
and demos use), ``generate_config`` (further ``GenerateConfig`` fields, e.g. ``temperature``,
``max_connections``), ``max_output_tokens``, ``reasoning_effort``, ``timeout_s``, ``retry``,
``images_in_tool_results``, ``label`` (how reports name the configuration: the model string).
"""
from __future__ import annotations

import asyncio
import json
import math
import os
import random
import re
import threading
import time
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import Any

from cab_core.errors import ConfigError, MissingDependency

from .google_provider import inline_schema
from .openai_provider import image_label, png_data_url, stop_reason
from .retry import RETRYABLE_KINDS, RetryPolicy, retry_after_s
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

INSTALL = "pip install 'cab-harness-reference[inspect]'"


def import_inspect():
    """``inspect_ai.model``, or :class:`MissingDependency` with the install command."""
    try:
        import inspect_ai.model as im
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise MissingDependency("inspect-ai (model provider 'inspect')", INSTALL) from e
    return im


# --- cab -> Inspect -----------------------------------------------------------------------------

def _image_content(img: Image) -> list:
    """An image as the harness shows it: its label, then the PNG."""
    from inspect_ai.model import ContentImage, ContentText

    return [ContentText(text=image_label(img)), ContentImage(image=png_data_url(img.png))]


def to_chat_messages(system: str, messages: list[Message], images_in_tool_results: bool = False) -> list:
    """cab's system prompt and messages as Inspect ``ChatMessage`` objects (see the module's doc)."""
    from inspect_ai.model import (
        ChatMessageAssistant,
        ChatMessageSystem,
        ChatMessageTool,
        ChatMessageUser,
        ContentReasoning,
        ContentText,
    )
    from inspect_ai.tool import ToolCall as InspectToolCall

    out: list = [ChatMessageSystem(content=system)] if system else []
    pending: list = []  # images of tool results a provider will not take in tool messages

    def flush() -> None:
        if pending:
            content: list = []
            for img in pending:
                content += _image_content(img)
            out.append(ChatMessageUser(content=content))
            pending.clear()

    for m in messages:
        if m.role != "tool":
            flush()
        if m.role == "system":
            continue
        if m.role == "user":
            content: list = []
            for p in m.parts:
                if isinstance(p, Text):
                    content.append(ContentText(text=p.text))
                elif isinstance(p, Image):
                    content += _image_content(p)
            if all(isinstance(c, ContentText) for c in content):
                out.append(ChatMessageUser(content="\n".join(c.text for c in content)))
            else:
                out.append(ChatMessageUser(content=content))
        elif m.role == "assistant":
            text = "\n".join(p.text for p in m.parts if isinstance(p, Text) and p.text)
            reasoning = [ContentReasoning(reasoning=p.text, signature=p.signature, redacted=not p.text)
                         for p in m.parts if isinstance(p, Thinking) and (p.text or p.signature)]
            calls = [InspectToolCall(id=c.call_id, function=c.name,
                                     arguments=c.arguments if isinstance(c.arguments, dict) else {},
                                     parse_error=None if isinstance(c.arguments, dict) else
                                     f"not a JSON object: {c.raw_arguments[:2000]}")
                     for c in m.parts if isinstance(c, ToolCall)]
            body: Any = [*reasoning, ContentText(text=text)] if reasoning else text
            out.append(ChatMessageAssistant(content=body, tool_calls=calls or None))
        elif m.role == "tool":
            for p in m.parts:
                if isinstance(p, ToolResult):
                    if p.images and images_in_tool_results:
                        parts: list = [ContentText(text=p.text)]
                        for img in p.images:
                            parts += _image_content(img)
                        out.append(ChatMessageTool(content=parts, tool_call_id=p.call_id, function=p.name))
                    else:
                        out.append(ChatMessageTool(content=p.text, tool_call_id=p.call_id, function=p.name))
                        pending.extend(p.images)
                elif isinstance(p, Image):
                    pending.append(p)
    flush()
    return out


def to_tool_infos(tools: list[ToolSpec]) -> list:
    """cab's tools as Inspect ``ToolInfo`` objects: name, description, and the JSON Schema of the
    arguments with its ``$defs``/``$ref`` inlined (Inspect's schema model holds no references).
    Inspect's ``JSONSchema`` keeps type, description, default, enum, items, properties,
    additionalProperties, anyOf, required and the bounds (pattern, min/maxLength, minimum/maximum);
    it drops ``title``, ``minItems``/``maxItems``, ``exclusiveMinimum``, ``default: null`` and the
    object's own ``description`` (and Inspect's OpenAI-compatible provider sends no bounds)."""
    from inspect_ai.tool import ToolInfo, ToolParams

    try:
        return [ToolInfo(name=t.name, description=t.description,
                         parameters=ToolParams.model_validate(inline_schema(t.parameters or {"type": "object"})))
                for t in tools]
    except ValueError as e:
        raise ConfigError(f"a tool schema Inspect cannot hold: {' '.join(str(e).split())[:300]}") from None


def to_inspect(system: str, messages: list[Message], tools: list[ToolSpec],
               images_in_tool_results: bool = False) -> tuple[list, list]:
    """One cab request (the system prompt, the context policy's messages, the tools) as Inspect's
    ``(list[ChatMessage], list[ToolInfo])``, ready for ``Model.generate(input, tools=...)``.
    ``images_in_tool_results``: keep a tool result's images in its ``ChatMessageTool`` (else they
    go into one user message after the tool messages, labelled)."""
    return to_chat_messages(system, messages, images_in_tool_results), to_tool_infos(tools)


# --- Inspect -> cab -----------------------------------------------------------------------------

def usage_from_inspect(u: Any) -> Usage:
    """Inspect's ``ModelUsage`` in cab's buckets (the same convention: input excludes the cache)."""
    if u is None:
        return Usage()
    return Usage(input_tokens=int(u.input_tokens or 0), output_tokens=int(u.output_tokens or 0),
                 reasoning_tokens=int(u.reasoning_tokens or 0),
                 cache_read_tokens=int(u.input_tokens_cache_read or 0),
                 cache_write_tokens=int(u.input_tokens_cache_write or 0))


def from_output(output: Any, model: str = "") -> Response:
    """Inspect's ``ModelOutput`` (its first choice) as a cab :class:`Response`. Raises
    ``ProviderError("context_length")`` for a ``model_length`` stop (the request outgrew the
    context window; Inspect turns the provider's refusal into that output)."""
    from inspect_ai.model import ContentReasoning, ContentText

    if not output.choices:
        raise ProviderError("server", f"empty output from {model or output.model} (no choices)", retryable=True)
    choice = output.choices[0]
    msg = choice.message
    if choice.stop_reason == "model_length":
        raise ProviderError("context_length", f"context length exceeded: {msg.text[:400]}", status=400,
                            reason="the request is over the model's context window")
    parts: list = []
    refusal = choice.stop_reason == "content_filter"
    texts: list[str] = []
    if isinstance(msg.content, str):
        texts = [msg.content] if msg.content else []
    else:
        for c in msg.content:
            if isinstance(c, ContentReasoning):
                parts.append(Thinking(text=c.summary if c.redacted and c.summary else ("" if c.redacted else c.reasoning),
                                      signature=c.signature, provider="inspect"))
            elif isinstance(c, ContentText) and c.text:
                texts.append(c.text)
                refusal = refusal or bool(c.refusal)
    if texts:
        parts.append(Text("\n".join(texts)))
    for tc in msg.tool_calls or []:
        if tc.parse_error:
            parts.append(ToolCall(call_id=tc.id, name=tc.function, arguments=None, raw_arguments=tc.parse_error))
        else:
            parts.append(ToolCall(call_id=tc.id, name=tc.function, arguments=dict(tc.arguments),
                                  raw_arguments=json.dumps(tc.arguments)))
    stop = stop_reason(parts, refusal=refusal, truncated=choice.stop_reason == "max_tokens",
                       finished=choice.stop_reason in ("stop", "tool_calls"))
    return Response(message=Message("assistant", parts), stop_reason=stop, usage=usage_from_inspect(output.usage),
                    model=output.model or model, latency_s=float(output.time or 0.0),
                    raw_stop_reason=str(choice.stop_reason))


# --- errors -------------------------------------------------------------------------------------

_CONTEXT_MARKERS = ("context_length_exceeded", "context length", "context window", "maximum context",
                    "prompt is too long", "too many tokens", "input is too long")


def _unwrap(exc: BaseException) -> BaseException:
    """The provider's own exception inside what Inspect raises when it gives up: tenacity's
    ``RetryError`` (the last try's exception) and Inspect's ``ModelGenerateError`` (its cause)."""
    for _ in range(5):
        last = getattr(exc, "last_attempt", None)  # tenacity.RetryError
        if last is not None and type(exc).__name__ == "RetryError":
            inner = last.exception()
            if inner is None:
                break
            exc = inner
        elif type(exc).__name__ == "ModelGenerateError" and exc.__cause__ is not None:
            exc = exc.__cause__
        else:
            break
    return exc


def _status(exc: BaseException) -> int | None:
    for attr in ("status_code", "status", "code"):
        v = getattr(exc, attr, None)
        if isinstance(v, int) and 100 <= v < 600:
            return v
    resp = getattr(exc, "response", None)
    v = getattr(resp, "status_code", None)
    return v if isinstance(v, int) else None


def classify_error(exc: BaseException) -> ProviderError:
    """Any exception from Inspect's ``Model.generate`` as a :class:`ProviderError` of cab's kinds:
    by the SDK's own classifier where the exception is the OpenAI, Anthropic or Google SDK's, else
    by its HTTP status, a connection failure, a timeout; ``other`` for anything else."""
    outer = exc
    exc = _unwrap(exc)
    if isinstance(exc, ProviderError):
        return exc
    module = type(exc).__module__ or ""
    err: ProviderError | None = None
    if module.startswith("openai"):
        from .openai_provider import classify_openai_error

        err = classify_openai_error(exc)
    elif module.startswith("anthropic"):
        from .anthropic_provider import classify as classify_anthropic

        err = classify_anthropic(exc)
    elif module.startswith("google.genai"):
        from .google_provider import GoogleProvider

        err = GoogleProvider.classify(exc)
    if err is None or err.kind == "other":
        err = _classify_generic(exc, outer) if err is None or err.status is None else err
    if err.retry_after_s is None:
        err.retry_after_s = retry_after_s(exc)
    if err.__cause__ is None:
        err.__cause__ = exc
    return err


def _classify_generic(exc: BaseException, outer: BaseException) -> ProviderError:
    name = type(exc).__name__
    names = {c.__name__ for c in type(exc).__mro__}
    msg = f"{name}: {' '.join(str(exc).split())}"[:1000]
    low = msg.lower()
    status = _status(exc) if _status(exc) is not None else _status(outer)
    if name in ("AttemptTimeoutError", "StreamIdleTimeoutError") or any("Timeout" in n for n in names) \
            or isinstance(exc, TimeoutError):
        return ProviderError("timeout", msg, status, reason="no answer within the timeout")
    reason = connection_reason(exc)
    if status is None and (names & {"ConnectError", "APIConnectionError", "ConnectionError"}
                           or isinstance(exc, ConnectionError)
                           or reason in ("connection refused", "name not resolved", "connection reset")):
        return ProviderError("unreachable", msg, reason=reason)
    if status in (401, 403):
        return ProviderError("auth", msg, status)
    if status == 402 or (status == 429 and ("insufficient_quota" in low or "quota" in low and "exceeded" in low)):
        return ProviderError("quota", msg, status)
    if status == 429:
        return ProviderError("rate_limit", msg, status)
    if status == 408:
        return ProviderError("timeout", msg, status)
    if status == 529 or (status is not None and status >= 500 and "overloaded" in low):
        return ProviderError("overloaded", msg, status)
    if status is not None and (status >= 500 or status in (409, 425)):
        return ProviderError("server", msg, status)
    if status in (400, 413, 422):
        kind = "context_length" if any(m in low for m in _CONTEXT_MARKERS) else "bad_request"
        return ProviderError(kind, msg, status)
    if status == 404:
        return ProviderError("other", msg, status, reason="HTTP 404: model or endpoint not found")
    return ProviderError("other", msg, status)


# --- the provider -------------------------------------------------------------------------------

_MARKUP = re.compile(r"\[/?[a-z ]+\]")  # rich markup in Inspect's PrerequisiteError messages


def _plain(message: Any) -> str:
    text = _MARKUP.sub("", str(message)).replace("ERROR:", "").strip()
    return " ".join(re.sub(r"\s*\n\s*\n\s*", ": ", text).split())


class _Slot:
    """One thread's event loop and Inspect model."""

    def __init__(self, runner: asyncio.Runner, model: Any):
        self.runner, self.model = runner, model
        self.waited = 0.0  # seconds slept between Inspect's tries of the current request
        self.tries = 1


def _close_slots(slots: list[_Slot], lock: threading.Lock) -> None:
    with lock:
        taken, slots[:] = list(slots), []
    for s in taken:
        try:
            s.runner.run(s.model.api.aclose())
        except Exception:  # noqa: BLE001 - a client that will not close must not keep its loop open
            pass
        s.runner.close()


class InspectProvider(Provider):
    name = "inspect"
    capabilities = Capabilities(images_in_tool_results=False, parallel_tool_calls=True, reasoning=True)

    def __init__(self, cfg: dict, *, sleep: Callable[[float], None] | None = None,
                 rng: random.Random | None = None):
        self.cfg = dict(cfg or {})
        self.model = str(self.cfg.get("model_id") or "")
        if "/" not in self.model:
            raise ConfigError(f"model.model_id={self.model or 'null'}: the inspect provider needs an Inspect "
                              "model string <provider>/<model> (e.g. openai/gpt-4o, anthropic/claude-sonnet-4-5, "
                              "openai-api/<service>/<model>, mockllm/model)")
        self._api_key_env = self.cfg.get("api_key_env") or None
        self._key_vars: tuple[str, ...] | None = (self._api_key_env,) if self._api_key_env else None
        self._base_url = self.cfg.get("base_url") or None
        self._api_base_url: str | None = None  # the base URL Inspect's provider resolved (its variable or default)
        self.timeout_s = self.cfg.get("timeout_s")
        self.retry = RetryPolicy.from_cfg(self.cfg.get("retry"), sleep=sleep or time.sleep, rng=rng or random.Random())
        model_args = self.cfg.get("model_args") or {}
        gen = self.cfg.get("generate_config") or {}
        if not isinstance(model_args, dict) or not isinstance(gen, dict):
            raise ConfigError("model.model_args and model.generate_config must be mappings")
        self.model_args, self.generate_config = dict(model_args), dict(gen)
        forced = self.cfg.get("images_in_tool_results")
        self._forced_images = None if forced is None else bool(forced)
        if self._forced_images is not None:
            self.capabilities = Capabilities(images_in_tool_results=self._forced_images, parallel_tool_calls=True,
                                             reasoning=True)
        self._local = threading.local()
        self._slots: list[_Slot] = []
        self._lock = threading.Lock()
        self._finalizer = weakref.finalize(self, _close_slots, self._slots, self._lock)

    # -- building ------------------------------------------------------------------------------
    def config(self):
        """The ``GenerateConfig`` of every request."""
        im = import_inspect()
        fields: dict[str, Any] = {"max_retries": max(0, self.retry.max_attempts - 1)}
        if self.cfg.get("max_output_tokens"):
            fields["max_tokens"] = int(self.cfg["max_output_tokens"])
        if self.cfg.get("reasoning_effort"):
            fields["reasoning_effort"] = self.cfg["reasoning_effort"]
        if self.timeout_s:
            fields["attempt_timeout"] = int(math.ceil(float(self.timeout_s)))
        fields.update(self.generate_config)
        try:
            return im.GenerateConfig(**fields)
        except ValueError as e:
            raise ConfigError(f"model.generate_config: {' '.join(str(e).split())[:300]}") from None

    def _model_args(self) -> dict:
        args = dict(self.model_args)
        outputs = args.get("custom_outputs")
        if isinstance(outputs, str):  # Inspect's mockllm: scripted outputs from a JSON file
            from inspect_ai.model import ModelOutput

            try:
                rows = json.loads(Path(outputs).read_text())
                args["custom_outputs"] = [ModelOutput.model_validate(r) for r in rows]
            except (OSError, ValueError, TypeError) as e:
                raise ConfigError(f"model.model_args.custom_outputs={outputs}: not a JSON list of Inspect "
                                  f"ModelOutput objects ({type(e).__name__}: {' '.join(str(e).split())[:200]})") from None
        return args

    def _build(self) -> Any:
        """A new Inspect ``Model`` for this configuration (in the running loop); the provider's
        missing key, SDK or unknown name as one ``ConfigError``."""
        im = import_inspect()
        from inspect_ai._util.error import PrerequisiteError

        key = None
        if self._api_key_env:
            key = os.environ.get(self._api_key_env)
            if not key:
                raise ConfigError(f"{self._api_key_env} is not set: export it with the API key for model "
                                  f"{self.model!r} (provider inspect)")
        try:
            model = im.get_model(self.model, config=self.config(), base_url=self._base_url, api_key=key,
                                 memoize=False, **self._model_args())
        except PrerequisiteError as e:  # its message names the variables, marked up: [blue]OPENAI_API_KEY[/blue]
            named = tuple(v for v in re.findall(r"\[blue\]([A-Za-z0-9_]+)\[/blue\]", str(e.message))
                          if re.search(r"KEY|TOKEN|SECRET|CREDENTIAL", v))
            self._key_vars = self._key_vars or named or None
            raise ConfigError(f"model.model_id={self.model}: {_plain(e.message)}") from None
        except (ValueError, TypeError, ImportError) as e:
            raise ConfigError(f"model.model_id={self.model}: Inspect cannot build this model "
                              f"({type(e).__name__}: {' '.join(str(e).split())[:300]})") from None
        if self._key_vars is None:
            self._key_vars = tuple(getattr(model.api, "api_key_vars", None) or ())
        base = getattr(model.api, "base_url", None)
        self._api_base_url = str(base).rstrip("/") if base else None
        if self._forced_images is None:
            self.capabilities = Capabilities(images_in_tool_results=bool(model.api.tool_result_images()),
                                             parallel_tool_calls=True, reasoning=True)
        return model

    def _slot(self) -> _Slot:
        slot = getattr(self._local, "slot", None)
        if slot is not None and slot in self._slots:
            return slot
        runner = asyncio.Runner()

        async def build():
            return self._build()

        try:
            model = runner.run(build())
        except BaseException:
            runner.close()
            raise
        slot = _Slot(runner, model)
        # Inspect's retry loop waits cab's backoff, and gives up where cab would (quota, auth, ...)
        model.api.retry_wait = lambda: self._wait(slot)
        model.api.should_retry = self._should_retry(model.api.should_retry)
        with self._lock:
            self._slots.append(slot)
        self._local.slot = slot
        return slot

    @staticmethod
    def _should_retry(inspects: Callable[[Exception], Any]) -> Callable[[Exception], Any]:
        """Inspect's retry decision, vetoed for what cab never retries: a spent quota (a 429 that
        waiting will not cure), refused credentials, a refused request."""
        def should_retry(ex: Exception) -> Any:
            if classify_error(ex).kind not in RETRYABLE_KINDS:
                return False
            return inspects(ex)
        return should_retry

    def _wait(self, slot: _Slot) -> Callable[[Any], float]:
        config = self.config()

        def wait(state: Any) -> float:
            # tenacity asks for the wait before its stop check: after the last try there is no wait
            if config.max_retries is not None and state.attempt_number > config.max_retries:
                return 0.0
            if config.timeout is not None and (state.seconds_since_start or 0.0) >= config.timeout:
                return 0.0
            exc = state.outcome.exception() if state.outcome is not None else None
            err = classify_error(exc) if exc is not None else ProviderError("other", "")
            after = err.retry_after_s
            if after is not None and self.retry.limiter is not None:
                self.retry.limiter.pause(min(after, self.retry.max_delay_s))  # every worker of the credential
            d = min(after, self.retry.max_delay_s) if after is not None else \
                self.retry.delay(err.kind, state.attempt_number)
            slot.waited += d
            slot.tries = state.attempt_number + 1
            return d
        return wait

    @property
    def key_envs(self) -> tuple[str, ...]:
        """The variables the key is read from: ``model.api_key_env``, else those Inspect's provider
        declares (``api_key_vars``, or the ones its missing-key error names); building the model
        (no network) where not known yet."""
        if self._key_vars is None:
            try:
                self._slot()
            except ConfigError:
                pass
        return self._key_vars or ()

    def check_credentials(self) -> None:
        """Builds this thread's Inspect model (no network): a missing key or SDK, or an unknown
        provider, raises ``ConfigError`` naming what Inspect's provider needs."""
        self._slot()

    @property
    def key_env(self) -> str | None:  # type: ignore[override]
        """The variable the key comes from: ``model.api_key_env``, else the first of Inspect's
        provider's variables that is set (what shared limits key a credential by)."""
        envs = self.key_envs
        return next((e for e in envs if os.environ.get(e)), envs[0] if envs else None)

    @property
    def base_url(self) -> str | None:
        """``model.base_url``, else the one Inspect's provider resolved, else ``inspect:<provider>``
        (what shared limits key an endpoint by, and what a failure names)."""
        return self._base_url or self._api_base_url or f"inspect:{self.model.split('/', 1)[0]}"

    def endpoint(self) -> str | None:
        return (self._base_url or self._api_base_url or "").rstrip("/") or None

    # -- one request -----------------------------------------------------------------------------
    def complete(self, system: str, messages: list[Message], tools: list[ToolSpec]) -> Response:
        slot = self._slot()
        inp, infos = to_inspect(system, messages, tools, self.capabilities.images_in_tool_results)
        slot.waited, slot.tries = 0.0, 1
        limiter = self.retry.limiter
        t0 = time.monotonic()
        try:
            if limiter is None:
                output = slot.runner.run(slot.model.generate(inp, tools=infos))
            else:
                with limiter.request(limiter.estimate) as grant:
                    try:
                        output = slot.runner.run(slot.model.generate(inp, tools=infos))
                    except BaseException:
                        grant.settle(0)
                        raise
                limiter.last_grant = grant
            resp = from_output(output, self.model)
        except Exception as e:  # noqa: BLE001 - every failure is classified
            err = classify_error(e)
            err.retryable = False  # Inspect has retried it
            err.attempts = slot.tries  # type: ignore[attr-defined]
            err.waited_s = slot.waited  # type: ignore[attr-defined]
            raise err.at(self.endpoint())  # noqa: B904 - its cause is the provider's own exception
        # waited: Inspect's sleeps between tries (the SDK's own retries, where on, are not seen and count
        # as the model's time); latency: the rest, Inspect's own work included
        resp.waited_s = slot.waited
        resp.latency_s = max(0.0, time.monotonic() - t0 - slot.waited)
        return resp

    def close(self) -> None:
        """Closes every thread's model client and event loop (the provider builds new ones if used again)."""
        _close_slots(self._slots, self._lock)


def factory(cfg: dict) -> InspectProvider:
    return InspectProvider(cfg)
