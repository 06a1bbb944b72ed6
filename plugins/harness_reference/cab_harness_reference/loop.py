"""The reference agent loop (FACTS A.10 "Loop"; paper Appendix "Reference harness").

One sequential model/message/tool loop: request → record the turn → run the response's tool
calls in order → append neutral tool results → repeat until the attempt ends. Retries live in
the provider (``retry.py``): a retried request never repeats an executed action. Provider
waiting time is credited back to the wall budget. A fork (``episode.fork``) starts with the
conversation its parent had up to the fork point, rebuilt from the parent's records."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING

from cab_core.errors import AttemptEnded, CabError, ConfigError
from cab_core.kits.harness import ToolResponse
from cab_core.kits.harness.agent_info import AgentRecord
from cab_core.kits.harness.catalog import motion_rules
from cab_core.kits.harness.conversation import REBUILT, transcript
from cab_core.kits.harness.limits import Limiter, LimitSettings, credential_key, endpoint_key
from cab_core.kits.harness.pricing import cost, usage_dict
from cab_core.kits.harness.prompts import first_user_message, result_images, run_code_limits, system_prompt
from cab_core.kits.registry import create_plugin

from . import checks
from .context import ContextOverflow, ReferenceContextPolicy
from .providers import PROVIDERS
from .retry import RetryPolicy
from .types import Capabilities, Image, Message, ProviderError, Response, Text, Thinking, ToolCall, ToolResult, ToolSpec

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.contracts.harness import AttemptSession, ModelCheck

MAX_NO_TOOL_TURNS = 3
CANCELLED = "cancelled: an earlier action in this response aborted"
MALFORMED_KEY = "__malformed_json_arguments__"
NUDGE = "Respond with tool calls."  # the user message after a response without a tool call


def _provider_name(model_cfg: dict) -> str:
    name = model_cfg.get("provider")
    if not name:
        raise ConfigError(f"model {model_cfg.get('name')!r}: the reference harness needs model.provider "
                          "(anthropic, openai, google, openai_compatible, inspect)")
    return str(name)


def create_provider(model_cfg: dict):
    """The provider named by ``model.provider``, through the plugin registry (falling back to this
    package's own providers when the plugin is not installed as an entry point)."""
    name = _provider_name(model_cfg)
    try:
        return create_plugin("model_providers", name, dict(model_cfg))
    except CabError:
        if name in PROVIDERS:
            return PROVIDERS[name](dict(model_cfg))
        raise


def limiter_for(model_cfg: dict, provider) -> Limiter | None:
    """The limits of ``model.limits`` (requests and tokens per minute per credential, requests in
    flight per provider endpoint), shared by every process of this user on this machine
    (:mod:`cab_core.kits.harness.limits`); None when the block sets none. The provider's retries are
    admitted by it too, and a ``Retry-After`` it gets pauses every worker of the credential."""
    settings = LimitSettings.from_cfg(model_cfg.get("limits"))
    if not settings.active:
        return None
    name = _provider_name(model_cfg)
    endpoint = getattr(provider, "base_url", None) or model_cfg.get("base_url") or "default"
    key_env = getattr(provider, "key_env", None)
    limiter = Limiter(credential_key(name, str(endpoint), os.environ.get(key_env) if key_env else None),
                      settings, slots_key=endpoint_key(name, str(endpoint)))
    for attr in ("retry", "retry_policy"):  # the providers' names for their RetryPolicy
        if isinstance(getattr(provider, attr, None), RetryPolicy):
            getattr(provider, attr).limiter = limiter
    return limiter


def request_tokens(resp: Response) -> int:
    """What a response counts against a tokens-per-minute limit: input (cache reads and writes
    included) and output tokens."""
    u = resp.usage
    return int(u.input_tokens + u.cache_read_tokens + u.cache_write_tokens + u.output_tokens)


def limited_complete(provider, limiter: Limiter | None, system: str, request: list[Message],
                     tools: list[ToolSpec], estimated_tokens: int) -> tuple[Response, float]:
    """``provider.complete`` under the limiter: each try the provider's retry loop sends holds a
    concurrency slot while in flight and a place under the per-minute limits taken just before it
    goes (:mod:`.retry`), reserved with ``estimated_tokens`` and settled here with the real usage.
    Returns the response and the seconds waited on limits; a ProviderError carries its wait in
    ``waited_on_limits_s``."""
    if limiter is None:
        return provider.complete(system, request, tools), 0.0
    before = limiter.waited_s
    limiter.estimate, limiter.last_grant = max(0, int(estimated_tokens)), None
    try:
        resp = provider.complete(system, request, tools)
    except ProviderError as e:
        e.waited_on_limits_s = limiter.waited_s - before  # type: ignore[attr-defined]
        raise
    if limiter.last_grant is not None:
        limiter.last_grant.settle(request_tokens(resp))
    return resp, limiter.waited_s - before


def _add_usage(totals: dict, resp: Response, c: dict) -> None:
    """Adds a turn's tokens, cost, waiting and latency to the attempt's totals."""
    for k, v in usage_dict(resp.usage).items():
        totals[k] += v
    totals["usd"] += c["usd"] or 0.0
    totals["waited_s"] += resp.waited_s
    totals["latency_s"] += resp.latency_s


def _record_turn(episode: AttemptSession, turn: int, resp: Response, c: dict, calls: list[ToolCall],
                 request_messages: int, estimated: int, on_limits: float = 0.0) -> None:
    """The ``model_turn`` event: what the model answered, what it cost, the request's size."""
    msg = resp.message
    episode.recorder.event(
        "model_turn", turn=turn, model=resp.model, request_id=resp.request_id,
        stop_reason=resp.stop_reason, raw_stop_reason=resp.raw_stop_reason,
        usage=usage_dict(resp.usage), cost=c, latency_s=round(resp.latency_s, 3),
        waited_s=round(resp.waited_s, 3), waited_on_limits_s=round(on_limits, 3), request_messages=request_messages,
        request_estimated_tokens=estimated,
        text="\n".join(p.text for p in msg.parts if isinstance(p, Text)),
        thinking="\n".join(p.text for p in msg.parts if isinstance(p, Thinking)),
        tool_calls=[{"call_id": p.call_id, "name": p.name, "arguments": p.arguments,
                     **({"raw_arguments": p.raw_arguments} if p.arguments is None else {}),
                     **({"salvaged": True} if p.salvaged else {})} for p in calls])


def _ended_without_calls(episode: AttemptSession, resp: Response, no_tool_turns: int) -> bool:
    """After a turn without tool calls (the ``no_tool_turns``-th in a row): ends the attempt on a
    refusal, on the output limit, or at ``MAX_NO_TOOL_TURNS`` such turns; whether it ended."""
    if resp.stop_reason == "refusal":
        episode.end("model_refusal", "the model refused")
    elif resp.stop_reason == "max_tokens":
        episode.end("output_length_exceeded", "the response hit the output limit without a tool call")
    elif no_tool_turns >= MAX_NO_TOOL_TURNS:
        episode.end("no_tool_calls", f"{MAX_NO_TOOL_TURNS} responses in a row without tool calls")
    else:
        return False
    return True


def sweep_folder(attempt_dir) -> Path | None:
    """The folder of the sweep an attempt's folder lies in (the one holding the sweep manifest,
    ``sweep.json``: cab_core.sweep.manifest.MANIFEST, not imported for a name), None for a single run."""
    if attempt_dir is None:
        return None
    for d in Path(attempt_dir).resolve().parents:
        if (d / "sweep.json").is_file():
            return d
    return None


class ReferenceHarness:
    """``ReferenceHarness(cfg).run(episode, model_cfg)``. ``provider`` / ``policy`` may be
    injected (tests); otherwise they come from the model config."""

    def __init__(self, cfg: dict | None = None, provider=None, policy=None):
        self.cfg = dict(cfg or {})
        self.provider = provider
        self.policy = policy
        self._owns_provider = False  # preflight built the provider (closed after the attempt)

    # -- before the simulator starts ----------------------------------------------------------
    def preflight(self, model_cfg: dict) -> None:
        """Build the provider and check its credentials without network; raises ConfigError
        naming the missing environment variable. The runner calls this before any simulator."""
        LimitSettings.from_cfg(model_cfg.get("limits"))  # a bad model.limits value: one line, before anything runs
        if self.provider is None:
            self.provider = create_provider(model_cfg)
            self._owns_provider = True
        self.provider.check_credentials()

    def before_build(self, spec) -> None:
        """Before the world is built (no attempt wall time spent): the endpoint probe of a local
        server (:meth:`_probe`), once per process, and once per sweep where the attempt is part of
        one (the profile is kept in the sweep's folder for its other workers)."""
        if self.provider is None:
            self.preflight(spec.model_cfg)
        self._probe(None, self.provider, spec.model_cfg, sweep_folder(getattr(spec, "output_dir", None)))

    def check_model(self, model_cfg: dict, network: bool = True) -> ModelCheck:
        """Credentials, and with ``network`` the endpoint, its model list and (an OpenAI-compatible
        server) its capabilities, before any attempt: :mod:`.checks`."""
        return checks.check_model(model_cfg, network, create_provider)

    # -- helpers ------------------------------------------------------------------------------
    @staticmethod
    def _tools(episode: AttemptSession) -> list[ToolSpec]:
        return [ToolSpec(t["name"], t.get("description", ""), t.get("parameters") or {"type": "object", "properties": {}})
                for t in episode.tool_specs()]

    def _policy(self, model_cfg: dict):
        if self.policy is not None:
            return self.policy
        cfg = dict(model_cfg.get("context") or {})
        name = cfg.pop("policy", "reference")
        try:  # context policies are plugins: a third party's policy is chosen by name
            return create_plugin("context_policies", name, cfg)
        except Exception:
            if name != "reference":
                raise
            return ReferenceContextPolicy.from_cfg(cfg)  # the plugin is not installed (tests from source)

    def _images(self, episode: AttemptSession, obs_ids: list[str], cap: int,
                call: ToolCall) -> tuple[list[Image], list[str]]:
        shown, withheld = result_images(episode, obs_ids, cap)
        return [Image(png, oid, f"{oid} from {call.name} ({call.call_id})") for oid, png in shown], withheld

    # -- the loop -----------------------------------------------------------------------------
    def run(self, episode: AttemptSession, model_cfg: dict) -> None:
        try:
            self._run(episode, model_cfg)
        finally:
            # a provider built here (not injected): its clients and event loops end with the attempt
            close = getattr(self.provider, "close", None) if self._owns_provider else None
            if callable(close):
                close()

    def _run(self, episode: AttemptSession, model_cfg: dict) -> None:
        if self.provider is None:
            self.preflight(model_cfg)
        provider = self.provider
        profile = self._probe(episode, provider, model_cfg)
        caps: Capabilities = provider.capabilities
        policy = self._policy(model_cfg)
        pricing = model_cfg.get("pricing")
        limit = model_cfg.get("context_tokens")
        limit = int(limit) if limit else None
        served = (profile or {}).get("effective_context_tokens")
        if isinstance(served, int) and served > 0 and (limit is None or served < limit):
            limit = served  # the server keeps less than configured (probe's needle test)
        max_images = int(getattr(policy, "max_images_per_result", 6))  # per tool result (FACTS A.7/A.10)
        tools = self._tools(episode)
        rc = run_code_limits(getattr(episode, "spec", None))
        system = system_prompt(episode.ledger.remaining(), motion_rules(), run_code=rc)
        fixed = int((len(system) + len(json.dumps([t.__dict__ for t in tools]))) / 4)
        history: list[Message] = [Message("user", [Text(first_user_message(episode.instruction))])]
        self._rebuild(episode, history, caps, max_images)
        no_tool_turns = 0
        forced_limit: int | None = None
        turn = 0
        max_turns = int(self.cfg.get("max_turns") or 4 * int(episode.ledger.tool_calls.limit) + 16)
        totals = {"input_tokens": 0, "output_tokens": 0, "reasoning_tokens": 0, "cache_read_tokens": 0,
                  "cache_write_tokens": 0, "usd": 0.0, "waited_s": 0.0, "latency_s": 0.0,
                  "waited_on_limits_s": 0.0}
        limiter = limiter_for(model_cfg, provider)
        last_output = 0  # the previous response's output tokens: the next request's estimate of its own

        while not episode.ended:
            if turn >= max_turns:
                episode.end("harness_turn_limit", f"{max_turns} model turns without the attempt ending")
                break
            # the wall clock is checked per model turn (FACTS A.9); the other budgets at tool dispatch
            exhausted = episode.ledger.exhausted_reason()
            if exhausted == "wall_budget":
                episode.end("wall_budget", "wall-clock budget spent before the next model turn")
                break
            if exhausted == "cost_budget":  # budget.cost_usd: no request once the spend has reached it
                episode.end("cost_budget", f"spend cap of {episode.spec.budget_cost_usd:g} USD reached "
                                           f"({totals['usd']:.4f} USD spent)")
                break
            turn += 1
            try:
                request = policy.build(history, caps, forced_limit or limit, fixed_tokens=fixed)
            except ContextOverflow as e:
                episode.recorder.event("context_overflow", turn=turn, estimated=e.estimated, limit=e.limit)
                episode.end("context_length_exceeded", str(e))
                break
            t0 = time.monotonic()
            try:
                resp, on_limits = limited_complete(provider, limiter, system, request, tools,
                                                   policy.estimate(request, fixed) + last_output)
            except ProviderError as e:
                on_limits = float(getattr(e, "waited_on_limits_s", 0.0))
                episode.ledger.credit_wall(on_limits)  # waiting on shared limits is not the model's time
                totals["waited_on_limits_s"] += on_limits
                forced_limit = self._provider_failed(episode, e, turn, t0, totals, policy, request, fixed,
                                                     limit, forced_limit)
                if forced_limit is None:
                    break
                continue
            episode.ledger.credit_wall(resp.waited_s + on_limits)
            totals["waited_on_limits_s"] += on_limits
            last_output = int(resp.usage.output_tokens)
            c = cost(resp.usage, pricing)
            _add_usage(totals, resp, c)
            episode.ledger.charge_cost(c["usd"] or 0.0)
            calls = [p for p in resp.message.parts if isinstance(p, ToolCall)]
            _record_turn(episode, turn, resp, c, calls, len(request), policy.estimate(request, fixed), on_limits)
            history.append(resp.message)
            if not calls:
                no_tool_turns += 1
                if _ended_without_calls(episode, resp, no_tool_turns):
                    break
                history.append(Message("user", [Text(NUDGE)]))
                continue
            no_tool_turns = 0
            self._run_calls(episode, calls, history, caps, max_images)
        episode.recorder.event("model_usage_total", **{k: round(v, 6) if isinstance(v, float) else v
                                                       for k, v in totals.items()}, turns=turn)
        self._record_usage(episode, totals, pricing)

    @staticmethod
    def _record_usage(episode: AttemptSession, totals: dict, pricing: dict | None) -> None:
        """``result.json``'s ``agent.usage``: tokens (input with cache reads and writes), spend (null
        without pricing), seconds waited on the shared limits and on retries."""
        agent = dict(getattr(episode, "agent", None) or AgentRecord("model_api", "config").as_dict())
        inputs = totals["input_tokens"] + totals["cache_read_tokens"] + totals["cache_write_tokens"]
        agent["usage"] = {"input_tokens": int(inputs), "output_tokens": int(totals["output_tokens"]),
                          "usd": round(totals["usd"], 6) if pricing else None,
                          "waited_on_limits_s": round(totals["waited_on_limits_s"], 3),
                          "waited_on_retries_s": round(totals["waited_s"], 3)}
        episode.agent = agent

    @staticmethod
    def _probe(episode: AttemptSession | None, provider, model_cfg: dict,
               cache_dir: Path | None = None) -> dict | None:
        """The endpoint's capability profile (:mod:`.probe`), probed on first use in this process
        (``model.probe``: auto probes local servers only) and applied to the provider; with the
        ``episode``, recorded as an ``endpoint_probe`` event and in ``result.json`` (``agent.serving``)."""
        from .probe import probe_endpoint, serving_summary, wants_probe

        if not hasattr(provider, "apply_profile"):
            return None
        profile = getattr(provider, "profile", None)
        if profile is None:
            if not wants_probe(model_cfg):
                return None
            profile = probe_endpoint(model_cfg, cache_dir=cache_dir)
            provider.apply_profile(profile)
        if episode is None:  # before the world is built: recorded once the attempt has started
            return profile
        episode.recorder.event("endpoint_probe", **{k: v for k, v in profile.items() if k != "kind"})
        if profile.get("reachable", True):
            episode.agent = AgentRecord("model_api", "config", serving=serving_summary(profile)).as_dict()
        return profile

    @staticmethod
    def _provider_failed(episode: AttemptSession, e: ProviderError, turn: int, t0: float, totals: dict,
                         policy, request: list[Message], fixed: int, limit: int | None,
                         forced_limit: int | None) -> int | None:
        """A request that failed after its retries: the wall time waited is credited back; a first
        context-length failure forces one compaction (FACTS A.10) and returns the context limit to
        retry with; any other failure ends the attempt and returns None."""
        waited = float(getattr(e, "waited_s", 0.0) or 0.0)
        episode.ledger.credit_wall(waited)
        totals["waited_s"] += waited
        if e.kind == "context_length" and forced_limit is None:
            # one forced-compaction retry (FACTS A.10), declined at the floor
            est = policy.estimate(request, fixed)
            forced_limit = int(min(est, limit or est) * 0.7)
            episode.recorder.event("forced_compaction", turn=turn, estimated=est, new_limit=forced_limit,
                                   error=str(e)[:240])
            return forced_limit
        if e.kind == "context_length":
            episode.end("context_length_exceeded", str(e)[:240])
            return None
        episode.recorder.event("provider_failure", turn=turn, error_kind=e.kind, status=e.status,
                               retryable=e.retryable, attempts=getattr(e, "attempts", None),
                               waited_s=round(waited, 3), message=str(e)[:1000], url=e.url,
                               infrastructure=e.infrastructure, latency_s=round(time.monotonic() - t0, 3))
        if e.infrastructure:  # an outage, the credentials, the quota: never scored (the detail is cab's one line)
            episode.end("provider_failure", e.summary())
        else:  # the request the model's conversation made was refused: the model's own, scored
            episode.end("provider_rejected", f"{e.kind}" + (f" (HTTP {e.status})" if e.status else "")
                        + f": {str(e)[:200]}")
        return None

    def _rebuild(self, episode: AttemptSession, history: list[Message], caps: Capabilities, max_images: int) -> None:
        """A fork goes on from the conversation its parent's model had up to the fork point, not
        from the instruction alone: what the model asked for and was told must match the world the
        fork starts in, or it would act on a history it never saw. The turns come from the parent's
        records (:func:`cab_core.kits.harness.conversation.transcript`); their results are built by the same code
        as live ones (:meth:`_run_calls`) from the recorded payloads and the observations the fork
        took again under the same ids, so the model sees them as it saw them then. Reasoning is not
        replayed: providers accept it only with the opaque token of the response it came from,
        which the records do not keep. Recorded as ``conversation_rebuilt``, with the turns as the
        model made them (``model_turns``), so a fork of this fork rebuilds them in turn."""
        fork = getattr(episode, "fork", None)  # a session written before forks has none
        if fork is None or episode.ended:
            return
        start = len(history)
        turns = transcript(fork.events)
        for t in turns:
            calls = [ToolCall(c["call_id"], c["name"], c["arguments"], c["raw_arguments"]) for c in t["calls"]]
            history.append(Message("assistant", ([Text(t["text"])] if t["text"] else []) + calls))
            if not calls:  # the parent's model went on after it: it was nudged
                history.append(Message("user", [Text(NUDGE)]))
                continue
            recorded = [ToolResponse(c["name"], dict(c["result"]), c["obs_ids"], status=c["status"]) if c["made"]
                        else None for c in t["calls"]]
            self._run_calls(episode, calls, history, caps, max_images, recorded)
        made = [c for t in turns for c in t["calls"] if c["made"]]
        images = sum(len(p.images) if isinstance(p, ToolResult) else isinstance(p, Image)
                     for m in history[start:] for p in m.parts)
        episode.recorder.event(
            REBUILT, at=fork.at, turns=len(turns), calls=len(made),
            cancelled=sum(not c["made"] for t in turns for c in t["calls"]), images=images,
            messages=len(history) - start,
            model_turns=[{"text": t["text"], "tool_calls": [
                {"call_id": c["call_id"], "name": c["name"], "arguments": c["arguments"],
                 **({"raw_arguments": c["raw_arguments"]} if c["raw_arguments"] else {})} for c in t["calls"]]}
                for t in turns])

    def _run_calls(self, episode: AttemptSession, calls: list[ToolCall], history: list[Message], caps: Capabilities,
                   max_images: int, recorded: list[ToolResponse | None] | None = None) -> None:
        """Make one response's calls in order and append their results to ``history``: one tool
        message per call, then (for a provider without images in tool results) one user message
        with the images. ``recorded``: the responses the calls got when the parent made them (a
        fork's rebuilt conversation, :meth:`_rebuild`), None for a call that was cancelled; the
        calls are then not made again, and their results are built exactly as live ones."""
        aborted = False
        results: list[ToolResult] = []
        followup: list = []
        for i, call in enumerate(calls):
            if episode.ended:
                results.append(ToolResult(call.call_id, call.name, json.dumps(
                    {"error": "not executed: the attempt has ended", "attempt_ended": True}), is_error=True))
                continue
            if aborted:
                results.append(ToolResult(call.call_id, call.name, json.dumps({"error": CANCELLED, "code": "cancelled"}),
                                          is_error=True))
                continue
            args = call.arguments
            malformed = args is None or not isinstance(args, dict)
            if malformed:  # charged like any invalid call (FACTS A.9)
                args = {MALFORMED_KEY: (call.raw_arguments or "")[:2000]}
            try:
                r = episode.call(call.name, args) if recorded is None else recorded[i]
            except AttemptEnded as e:
                results.append(ToolResult(call.call_id, call.name, json.dumps({"error": str(e), "attempt_ended": True}),
                                          is_error=True))
                continue
            payload = dict(r.payload)
            if malformed and payload.get("code") == "invalid_tool_arguments":
                payload["error"] = ("bad arguments: the arguments are not a valid JSON object: "
                                    + (call.raw_arguments or "")[:200])
            imgs, withheld = self._images(episode, r.obs_ids, max_images, call)
            if withheld:
                payload.setdefault("images_not_attached", withheld)
            is_error = bool(payload.get("error"))
            text = json.dumps(payload, default=str)
            if caps.images_in_tool_results:
                results.append(ToolResult(call.call_id, call.name, text, images=imgs, is_error=is_error))
            else:
                if imgs:
                    text += "\n" + "Images attached in the next user message: " + ", ".join(i.obs_id for i in imgs)
                results.append(ToolResult(call.call_id, call.name, text, is_error=is_error))
                for im in imgs:
                    followup += [Text(f"[image {im.label}]"), im]
            if r.status == "ABORTED":
                aborted = True
        for res in results:
            history.append(Message("tool", [res]))
        if followup:
            history.append(Message("user", followup))
