"""Bounded retries of one model request (FACTS A.10 "Retries"): exponential backoff with full
jitter on rate limits, timeouts and server errors; never on auth, bad requests or context length.

A retried request never repeats an executed action: the loop retries only the model request,
before any tool of that response runs. The time spent waiting is returned so the loop can credit
it back to the wall budget (provider outage is not the model's time).

A ``Retry-After`` (or ``retry-after-ms``) the server sends with a rate limit or an overload is
honoured: the retry waits that long instead of the backoff's draw, and, when the policy has a
``limiter`` (:class:`cab_core.kits.harness.limits.Limiter`), every process sharing the credential
is paused until then. With a limiter, each try (retries included) is sent inside
``limiter.request``: a concurrency slot held while it is in flight, a place under the per-minute
limits taken just before it goes (``limiter.estimate`` tokens; the caller settles the real usage
through ``limiter.last_grant``)."""
from __future__ import annotations

import email.utils
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import TYPE_CHECKING, TypeVar

from .types import ProviderError

if TYPE_CHECKING:  # pragma: no cover
    from cab_core.kits.harness.limits import Limiter

T = TypeVar("T")

RETRYABLE_KINDS = frozenset({"rate_limit", "timeout", "server", "overloaded", "unreachable"})


@dataclass
class RetryPolicy:
    """``max_attempts`` requests in all; delay before retry *n* (1-based) is drawn uniformly from
    ``[0, min(max_delay_s, base_delay_s[kind] * 2**(n-1))]`` (full jitter)."""
    max_attempts: int = 3
    base_delay_s: dict = field(default_factory=lambda: {"rate_limit": 60.0, "timeout": 2.0, "server": 2.0})
    max_delay_s: float = 300.0
    sleep: Callable[[float], None] = time.sleep
    rng: random.Random = field(default_factory=random.Random)
    limiter: Limiter | None = None  # shared limits: a Retry-After pauses every worker; retries are admitted

    @classmethod
    def from_cfg(cls, cfg: dict | None, **kw) -> RetryPolicy:
        cfg = dict(cfg or {})
        p = cls(**kw)
        if "max_attempts" in cfg:
            p.max_attempts = max(1, int(cfg["max_attempts"]))
        if "max_delay_s" in cfg:
            p.max_delay_s = float(cfg["max_delay_s"])
        for k, v in (cfg.get("base_delay_s") or {}).items():
            p.base_delay_s[str(k)] = float(v)
        return p

    def delay(self, kind: str, retry_index: int) -> float:
        base = float(self.base_delay_s.get(kind, 2.0))
        cap = min(self.max_delay_s, base * (2 ** max(0, retry_index - 1)))
        return self.rng.uniform(0.0, cap)


def retry_after_s(exc: BaseException | None) -> float | None:
    """The seconds a server asked to wait, from the ``retry-after-ms`` or ``Retry-After`` header
    (seconds or an HTTP date) of the HTTP response an SDK exception carries; None without one."""
    headers = getattr(getattr(exc, "response", None), "headers", None)
    if not headers:
        return None
    for name in ("retry-after-ms", "retry-after"):
        v = headers.get(name)
        if v is None:
            continue
        try:
            s = float(v)
        except (TypeError, ValueError):
            try:
                when = email.utils.parsedate_to_datetime(str(v))
            except (TypeError, ValueError):
                continue
            if when.tzinfo is None:
                when = when.replace(tzinfo=timezone.utc)
            s = (when - datetime.now(timezone.utc)).total_seconds()
        else:
            s = s / 1000.0 if name == "retry-after-ms" else s
        return max(0.0, s)
    return None


def call_with_retries(fn: Callable[[], T], classify: Callable[[BaseException], ProviderError],
                      policy: RetryPolicy | None = None) -> tuple[T, float]:
    """Run ``fn`` until it succeeds or a non-retryable error / the attempt bound is hit.

    ``classify`` maps any exception from ``fn`` to a :class:`ProviderError` (its ``kind`` decides
    whether to retry). Returns ``(result, waited_s)``; raises the last ``ProviderError`` (with
    ``waited_s`` attached as an attribute) when giving up."""
    policy = policy or RetryPolicy()
    waited = 0.0
    attempt = 0
    while True:
        attempt += 1
        try:
            if policy.limiter is None:
                return fn(), waited
            with policy.limiter.request(policy.limiter.estimate) as grant:  # a slot, a place under the limits
                try:
                    result = fn()
                except BaseException:
                    grant.settle(0)  # a refused or failed try is not counted in tokens
                    raise
            policy.limiter.last_grant = grant  # the caller settles the tokens the answer used
            return result, waited
        except Exception as e:  # noqa: BLE001 - every failure is classified
            err = e if isinstance(e, ProviderError) else classify(e)
            if err is not e and err.__cause__ is None:
                err.__cause__ = e
            retryable = err.kind in RETRYABLE_KINDS
            err.retryable = retryable
            after = getattr(err, "retry_after_s", None)
            if after is None:
                after = retry_after_s(e)
                err.retry_after_s = after
            if after is not None and policy.limiter is not None and err.kind in RETRYABLE_KINDS:
                policy.limiter.pause(min(after, policy.max_delay_s))  # every worker of the credential waits
            if not retryable or attempt >= policy.max_attempts:
                err.attempts = attempt  # type: ignore[attr-defined]
                err.waited_s = waited  # type: ignore[attr-defined]
                raise err  # noqa: B904 - the cause is set above, only where err has none (err may be e itself)
            d = min(after, policy.max_delay_s) if after is not None else policy.delay(err.kind, attempt)
            t0 = time.monotonic()
            policy.sleep(d)
            waited += max(d, time.monotonic() - t0)
