"""Comparisons with their uncertainty: pass@k and pass^k, paired comparisons of two
configurations, and how many attempts a comparison needs. Pure functions over success counts and
outcomes (no records, no simulator); the formulas and a worked example are in docs/statistics.md.

* :func:`pass_at_k`, :func:`pass_hat_k`: the unbiased estimators over ``n`` attempts of a task with
  ``c`` successes, ``1 - C(n-c, k)/C(n, k)`` and ``C(c, k)/C(n, k)``; :func:`pass_k_curve` averages
  them over tasks (equal weight) for k = 1..n.
* :func:`mcnemar_exact`: the exact McNemar test on discordant attempt pairs (two-sided binomial
  p-value at 1/2); :func:`pair_attempts` forms the pairs (attempt i of A with attempt i of B on the
  same task instance).
* :func:`paired_bootstrap`: the difference in success rate over shared instances with a
  percentile interval, resampling instances with replacement (seeded).
* :func:`attempts_needed`: attempts per configuration to detect a difference between two success
  rates (normal approximation for two independent proportions, pooled variance under H0, no
  continuity correction), and :func:`plan` spreading them over tasks; :func:`pairs_needed`, the
  attempt pairs a paired comparison (McNemar) needs given the share of discordant pairs (Connor
  1987), :func:`mcnemar_exact_power`, the exact power of :func:`mcnemar_exact` at n pairs, and
  :func:`pairs_needed_exact`, the pairs the exact test needs.

The exact test and the normal quantiles use only the standard library (``math.comb``,
``statistics.NormalDist``); the bootstrap uses numpy.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

Instance = tuple  # (task, seed): one task instance; attempts on the same instance are paired


# ---------------------------------------------------------------------------------------------
# pass@k and pass^k
# ---------------------------------------------------------------------------------------------
def _check(n: int, c: int, k: int) -> None:
    if not (0 <= c <= n and 1 <= k <= n):
        raise ValueError(f"need 0 <= c <= n and 1 <= k <= n (n={n}, c={c}, k={k})")


def pass_at_k(n: int, c: int, k: int) -> float:
    """Probability that at least one of k attempts drawn without replacement from the n
    (c successful) succeeds: ``1 - C(n-c, k) / C(n, k)``."""
    _check(n, c, k)
    return 1.0 - math.comb(n - c, k) / math.comb(n, k)


def pass_hat_k(n: int, c: int, k: int) -> float:
    """Probability that all k attempts drawn without replacement succeed: ``C(c, k) / C(n, k)``."""
    _check(n, c, k)
    return math.comb(c, k) / math.comb(n, k)


def pass_k_curve(per_task: dict[str, tuple[int, int]]) -> dict[str, list[int] | list[float]]:
    """``{"k": [1..K], "pass_at_k": [...], "pass_hat_k": [...]}`` averaged over tasks with equal
    weight, from ``task -> (n attempts, c successes)``; K is the smallest n over the tasks (a task
    with fewer attempts has no estimate for larger k). Empty lists when there is no task."""
    counts = [(n, c) for n, c in per_task.values() if n > 0]
    if not counts:
        return {"k": [], "pass_at_k": [], "pass_hat_k": []}
    ks = list(range(1, min(n for n, _ in counts) + 1))
    return {"k": ks,
            "pass_at_k": [sum(pass_at_k(n, c, k) for n, c in counts) / len(counts) for k in ks],
            "pass_hat_k": [sum(pass_hat_k(n, c, k) for n, c in counts) / len(counts) for k in ks]}


# ---------------------------------------------------------------------------------------------
# paired comparisons
# ---------------------------------------------------------------------------------------------
def binom_two_sided_half(k: int, n: int) -> float:
    """Exact two-sided p-value of k successes in n trials at p = 1/2: twice the smaller tail,
    capped at 1 (the same as summing every outcome no more likely than k, since the
    distribution is symmetric)."""
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(k, n - k) + 1))
    return min(1.0, 2 * tail / 2 ** n)


def mcnemar_exact(b: int, c: int) -> float:
    """Exact McNemar test: two-sided p-value of ``b`` pairs where only A succeeded against ``c``
    where only B did (concordant pairs carry no information); 1.0 with no discordant pair."""
    return binom_two_sided_half(b, b + c)


@dataclass
class Pairs:
    """Attempt pairs on shared instances: both succeeded, only A, only B, neither."""
    both: int = 0
    only_a: int = 0  # McNemar's b
    only_b: int = 0  # McNemar's c
    neither: int = 0

    @property
    def n(self) -> int:
        return self.both + self.only_a + self.only_b + self.neither


def pair_attempts(a: dict[Instance, dict[int, bool]], b: dict[Instance, dict[int, bool]]) -> Pairs:
    """Pairs attempt i of A with attempt i of B on every instance both ran (attempt numbers that
    only one side has are left out)."""
    out = Pairs()
    for inst in sorted(set(a) & set(b)):
        for i in sorted(set(a[inst]) & set(b[inst])):
            x, y = a[inst][i], b[inst][i]
            if x and y:
                out.both += 1
            elif x:
                out.only_a += 1
            elif y:
                out.only_b += 1
            else:
                out.neither += 1
    return out


def paired_bootstrap(a: dict[Instance, list[bool]], b: dict[Instance, list[bool]], resamples: int = 10_000,
                     confidence: float = 0.95, seed: int = 0) -> dict:
    """Difference in success rate, A minus B, over the instances both ran: each instance's rate
    difference (its attempts' success rate under A minus under B), averaged over instances; the
    percentile interval resamples instances with replacement (numpy's PCG64 seeded with
    ``seed``). ``{"instances", "difference", "ci", "confidence", "resamples", "seed"}``;
    ``difference`` and ``ci`` are None with no shared instance."""
    shared = sorted(inst for inst in set(a) & set(b) if a[inst] and b[inst])
    out: dict[str, Any] = {"instances": len(shared), "difference": None, "ci": None, "confidence": confidence,
                           "resamples": resamples, "seed": seed}
    if not shared:
        return out
    d = np.array([np.mean(a[i]) - np.mean(b[i]) for i in shared], dtype=float)
    rng = np.random.default_rng(seed)
    means = d[rng.integers(0, len(d), size=(resamples, len(d)))].mean(axis=1)
    tail = (1 - confidence) / 2
    lo, hi = np.quantile(means, [tail, 1 - tail])
    out.update(difference=float(d.mean()), ci=(float(lo), float(hi)))
    return out


def compare(a: dict[Instance, dict[int, bool]], b: dict[Instance, dict[int, bool]], resamples: int = 10_000,
            confidence: float = 0.95, seed: int = 0) -> dict:
    """The paired comparison of A and B from ``instance -> attempt number -> success``: the
    McNemar counts and exact p-value on attempt pairs, and the paired bootstrap over instances."""
    p = pair_attempts(a, b)
    boot = paired_bootstrap({i: list(v.values()) for i, v in a.items()}, {i: list(v.values()) for i, v in b.items()},
                            resamples, confidence, seed)
    return {"pairs": p.n, **asdict(p), "mcnemar_p": mcnemar_exact(p.only_a, p.only_b), "bootstrap": boot}


# ---------------------------------------------------------------------------------------------
# how many attempts
# ---------------------------------------------------------------------------------------------
def attempts_needed(p1: float, p2: float, alpha: float = 0.05, power: float = 0.80) -> int:
    """Attempts per configuration for a two-sided test at ``alpha`` to tell success rates ``p1``
    and ``p2`` apart with probability ``power``: the normal approximation for two independent
    proportions with the pooled variance under H0 (Fleiss, Levin & Paik, Statistical Methods for
    Rates and Proportions, ch. 4, without the
    continuity correction), rounded up::

        n = (z_{1-alpha/2} sqrt(2 pbar qbar) + z_{power} sqrt(p1 q1 + p2 q2))^2 / (p1 - p2)^2
    """
    if not (0 <= p1 <= 1 and 0 <= p2 <= 1) or p1 == p2:
        raise ValueError(f"need two different rates in [0, 1] (got {p1}, {p2})")
    if not (0 < alpha < 1 and 0 < power < 1):
        raise ValueError(f"need 0 < alpha < 1 and 0 < power < 1 (got {alpha}, {power})")
    z = NormalDist().inv_cdf
    pbar = (p1 + p2) / 2
    num = z(1 - alpha / 2) * math.sqrt(2 * pbar * (1 - pbar)) + z(power) * math.sqrt(p1 * (1 - p1) + p2 * (1 - p2))
    return math.ceil(num ** 2 / (p1 - p2) ** 2 - 1e-9)


def pairs_needed(difference: float, discordant: float, alpha: float = 0.05, power: float = 0.80) -> int:
    """Attempt pairs for the paired (McNemar) test at two-sided ``alpha`` to detect a difference
    ``difference`` = p10 - p01 in success rate with probability ``power``, when a share
    ``discordant`` = p10 + p01 of the pairs have one success and one failure (Connor, "Sample size
    for testing differences in proportions for the paired-sample design", Biometrics 43, 1987)::

        n = (z_{1-alpha/2} sqrt(pd) + z_{power} sqrt(pd - delta^2))^2 / delta^2

    The fewer discordant pairs (configurations that succeed on the same tasks), the fewer pairs."""
    d, pd = abs(float(difference)), float(discordant)
    if not 0 < d <= pd <= 1:
        raise ValueError(f"need 0 < |difference| <= discordant share <= 1 (got {difference}, {discordant})")
    if not (0 < alpha < 1 and 0 < power < 1):
        raise ValueError(f"need 0 < alpha < 1 and 0 < power < 1 (got {alpha}, {power})")
    z = NormalDist().inv_cdf
    num = z(1 - alpha / 2) * math.sqrt(pd) + z(power) * math.sqrt(max(pd - d * d, 0.0))
    return math.ceil(num ** 2 / d ** 2 - 1e-9)


def _binom_pmf(m: int, p: float) -> np.ndarray:
    """Binomial(m, p) probabilities of 0..m (log-space, exact to float rounding)."""
    k = np.arange(m + 1)
    if p <= 0 or p >= 1:
        return (k == (0 if p <= 0 else m)).astype(float)
    lg = np.array([math.lgamma(i + 1) for i in range(m + 1)])
    return np.exp(lg[m] - lg - lg[::-1] + k * math.log(p) + (m - k) * math.log1p(-p))


def mcnemar_exact_power(n: int, p10: float, p01: float, alpha: float = 0.05) -> float:
    """The probability that :func:`mcnemar_exact` rejects at ``alpha`` with ``n`` pairs, of which
    each is (A only) with probability ``p10`` and (B only) with ``p01``, computed exactly: the
    discordant count m is Binomial(n, p10 + p01) and, given m, A's count b is Binomial(m,
    p10 / (p10 + p01)); the test rejects when min(b, m - b) <= k*(m), the largest k with
    2 P(Binomial(m, 1/2) <= k) <= alpha."""
    pd = p10 + p01
    if n < 1 or pd <= 0:
        return 0.0
    q = p10 / pd
    pm = _binom_pmf(n, pd)
    total = 0.0
    for m in range(1, n + 1):
        if pm[m] < 1e-15:
            continue
        tail = np.cumsum(_binom_pmf(m, 0.5))
        ks = np.nonzero(2 * tail[: (m + 1) // 2] <= alpha + 1e-12)[0]
        if not len(ks):
            continue
        k = int(ks[-1])
        f = _binom_pmf(m, q)
        total += pm[m] * (f[: k + 1].sum() + f[m - k:].sum())
    return float(total)


def pairs_needed_exact(difference: float, discordant: float, alpha: float = 0.05, power: float = 0.80) -> int:
    """The smallest number of pairs, from :func:`pairs_needed` up, at which the exact McNemar test
    (:func:`mcnemar_exact`, the one ``--compare`` runs) reaches ``power``
    (:func:`mcnemar_exact_power`). The exact test is conservative, so this is a few per cent above
    the approximation; its power is not monotone in n (the test is discrete), so a larger n may
    fall back just below ``power``."""
    n0 = pairs_needed(difference, discordant, alpha, power)
    d = abs(float(difference))
    p10, p01 = (discordant + d) / 2, (discordant - d) / 2
    for n in range(n0, 4 * n0 + 50):
        if mcnemar_exact_power(n, p10, p01, alpha) >= power:
            return n
    raise ValueError(f"no n up to {4 * n0 + 50} reaches power {power}")  # pragma: no cover


def plan(difference: float, baseline: float = 0.5, tasks: int = 25, alpha: float = 0.05, power: float = 0.80,
         discordant: float | None = None) -> dict:
    """Attempts per configuration to detect ``difference`` in success rate around ``baseline``
    (the rates ``baseline - difference/2`` and ``baseline + difference/2``, clipped into [0, 1]),
    and the attempts per task when they are spread over ``tasks`` tasks. It treats attempts as
    independent: where tasks differ in difficulty, attempts of a task are correlated and more are
    needed (see docs/statistics.md)."""
    if not 0 < difference <= 1:
        raise ValueError(f"the difference must be in (0, 1] (got {difference})")
    if tasks < 1:
        raise ValueError(f"need at least one task (got {tasks})")
    lo = min(max(baseline - difference / 2, 0.0), 1.0 - difference)
    p1, p2 = lo, lo + difference
    n = attempts_needed(p1, p2, alpha, power)
    per_task = math.ceil(n / tasks)
    out = {"difference": difference, "rates": (p1, p2), "alpha": alpha, "power": power,
           "method": "normal approximation, two independent proportions, pooled variance under H0, "
                     "no continuity correction",
           "attempts_per_config": n, "tasks": tasks, "attempts_per_task": per_task,
           "attempts_per_config_rounded": per_task * tasks, "paired": None}
    if discordant is not None:
        approx = pairs_needed(difference, discordant, alpha, power)
        pairs = pairs_needed_exact(difference, discordant, alpha, power)
        out["paired"] = {"discordant": discordant, "pairs": pairs, "pairs_per_task": math.ceil(pairs / tasks),
                         "pairs_approximation": approx,
                         "method": "exact McNemar test, smallest n from Connor's (1987) approximation up "
                                   "that reaches the power"}
    return out
