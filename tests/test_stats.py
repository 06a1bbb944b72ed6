"""cab_core.analysis.stats against hand-computed cases, scipy and statsmodels, and a published table."""
import itertools
import math

import numpy as np
import pytest

from cab_core.analysis import stats as st


# ---------------------------------------------------------------------------------------------
# pass@k and pass^k
# ---------------------------------------------------------------------------------------------
def test_pass_k_by_hand():
    # n = 3 attempts, c = 1 success: pass@1 = 1/3, pass@2 = 1 - C(2,2)/C(3,2) = 2/3, pass@3 = 1;
    # pass^1 = 1/3, pass^2 = C(1,2)/C(3,2) = 0, pass^3 = 0
    assert [st.pass_at_k(3, 1, k) for k in (1, 2, 3)] == pytest.approx([1 / 3, 2 / 3, 1.0])
    assert [st.pass_hat_k(3, 1, k) for k in (1, 2, 3)] == pytest.approx([1 / 3, 0.0, 0.0])
    # c = 2: pass@2 = 1 - C(1,2)/C(3,2) = 1, pass^2 = C(2,2)/C(3,2) = 1/3
    assert st.pass_at_k(3, 2, 2) == 1.0 and st.pass_hat_k(3, 2, 2) == pytest.approx(1 / 3)
    # edges: never / always
    assert st.pass_at_k(3, 0, 3) == 0.0 and st.pass_hat_k(3, 3, 3) == 1.0
    with pytest.raises(ValueError):
        st.pass_at_k(3, 1, 4)
    with pytest.raises(ValueError):
        st.pass_hat_k(3, 4, 1)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_pass_k_equals_enumerating_every_k_subset(n):
    # the estimators are the fraction of k-subsets of the n attempts with any / all successes
    for c in range(n + 1):
        outcomes = [True] * c + [False] * (n - c)
        for k in range(1, n + 1):
            subsets = list(itertools.combinations(outcomes, k))
            assert st.pass_at_k(n, c, k) == pytest.approx(sum(any(s) for s in subsets) / len(subsets))
            assert st.pass_hat_k(n, c, k) == pytest.approx(sum(all(s) for s in subsets) / len(subsets))


def test_pass_k_curve_averages_tasks_with_equal_weight():
    # three tasks of 3 attempts with 3, 1 and 0 successes
    curve = st.pass_k_curve({"a": (3, 3), "b": (3, 1), "c": (3, 0)})
    assert curve["k"] == [1, 2, 3]
    assert curve["pass_at_k"] == pytest.approx([(1 + 1 / 3 + 0) / 3, (1 + 2 / 3 + 0) / 3, (1 + 1 + 0) / 3])
    assert curve["pass_hat_k"] == pytest.approx([(1 + 1 / 3 + 0) / 3, 1 / 3, 1 / 3])
    # k stops at the smallest n; no task, no curve
    assert st.pass_k_curve({"a": (3, 2), "b": (2, 1)})["k"] == [1, 2]
    assert st.pass_k_curve({}) == {"k": [], "pass_at_k": [], "pass_hat_k": []}


# ---------------------------------------------------------------------------------------------
# McNemar
# ---------------------------------------------------------------------------------------------
def test_mcnemar_by_hand():
    # b = 5, c = 0: 2 * (1/2)^5 = 1/16; b = 1, c = 1: 1; none discordant: 1
    assert st.mcnemar_exact(5, 0) == pytest.approx(1 / 16)
    assert st.mcnemar_exact(0, 5) == pytest.approx(1 / 16)
    assert st.mcnemar_exact(1, 1) == 1.0 and st.mcnemar_exact(0, 0) == 1.0
    # b = 1, c = 7: 2 * (1 + 8) / 256 = 0.0703125
    assert st.mcnemar_exact(1, 7) == pytest.approx(18 / 256)


def test_mcnemar_matches_scipy_binomtest():
    from scipy.stats import binomtest

    for b in range(0, 31):
        for c in range(0, 31):
            if b + c == 0:
                continue
            want = binomtest(b, b + c, 0.5, alternative="two-sided").pvalue
            assert st.mcnemar_exact(b, c) == pytest.approx(want, rel=1e-9, abs=1e-15), (b, c)


def test_mcnemar_matches_statsmodels():
    from statsmodels.stats.contingency_tables import mcnemar

    for both, b, c, neither in [(10, 1, 7, 5), (3, 12, 4, 9), (0, 0, 6, 0), (20, 9, 9, 2), (1, 30, 15, 1)]:
        want = mcnemar(np.array([[both, b], [c, neither]]), exact=True).pvalue
        assert st.mcnemar_exact(b, c) == pytest.approx(want, rel=1e-9), (b, c)


def test_attempt_pairs_on_shared_instances():
    a = {("t1", 0): {1: True, 2: True, 3: False}, ("t2", 0): {1: False, 2: False, 3: True},
         ("only_a", 0): {1: True}}
    b = {("t1", 0): {1: True, 2: False, 3: False}, ("t2", 0): {1: True, 2: False},
         ("t1", 5): {1: True}}  # another seed of t1 is another instance: not shared
    p = st.pair_attempts(a, b)
    # t1: (T,T) (T,F) (F,F); t2: (F,T) (F,F); attempt 3 of t2 has no partner
    assert (p.both, p.only_a, p.only_b, p.neither, p.n) == (1, 1, 1, 2, 5)
    r = st.compare(a, b, resamples=200)
    assert (r["pairs"], r["only_a"], r["only_b"], r["mcnemar_p"]) == (5, 1, 1, 1.0)
    assert r["bootstrap"]["instances"] == 2


# ---------------------------------------------------------------------------------------------
# paired bootstrap
# ---------------------------------------------------------------------------------------------
def test_bootstrap_point_estimate_and_degenerate_interval():
    # every instance: A 3/3, B 1/3 -> difference 2/3 everywhere, so the interval is a point
    a = {(f"t{i}", 0): [True] * 3 for i in range(5)}
    b = {(f"t{i}", 0): [True, False, False] for i in range(5)}
    r = st.paired_bootstrap(a, b, resamples=500)
    assert r["difference"] == pytest.approx(2 / 3) and r["ci"] == pytest.approx((2 / 3, 2 / 3))
    assert st.paired_bootstrap(a, {}, resamples=10)["difference"] is None


def test_bootstrap_is_seeded_and_matches_a_direct_resampling():
    rng = np.random.default_rng(7)
    a = {(f"t{i}", 0): list(rng.random(3) < 0.7) for i in range(25)}
    b = {(f"t{i}", 0): list(rng.random(3) < 0.4) for i in range(25)}
    r1 = st.paired_bootstrap(a, b, resamples=2000, seed=3)
    assert r1 == st.paired_bootstrap(a, b, resamples=2000, seed=3)
    assert r1["ci"] != st.paired_bootstrap(a, b, resamples=2000, seed=4)["ci"]
    # the same resampling written out longhand, one resample at a time
    keys = sorted(a)
    d = [np.mean(a[k]) - np.mean(b[k]) for k in keys]
    g = np.random.default_rng(3)
    idx = g.integers(0, 25, size=(2000, 25))
    means = sorted(sum(d[j] for j in row) / 25 for row in idx)
    assert r1["difference"] == pytest.approx(sum(d) / 25)
    assert r1["ci"] == pytest.approx(tuple(np.quantile(means, [0.025, 0.975])))
    assert r1["ci"][0] < r1["difference"] < r1["ci"][1]


def test_bootstrap_interval_covers_like_the_normal_interval():
    # many instances: the percentile interval approaches mean +- 1.96 sd/sqrt(n) of the differences
    rng = np.random.default_rng(1)
    a = {(i, 0): [bool(x)] for i, x in enumerate(rng.random(400) < 0.6)}
    b = {(i, 0): [bool(x)] for i, x in enumerate(rng.random(400) < 0.5)}
    r = st.paired_bootstrap(a, b, resamples=10_000)
    d = np.array([float(a[k][0]) - float(b[k][0]) for k in sorted(a)])
    half = 1.959964 * d.std() / math.sqrt(len(d))
    assert r["ci"] == pytest.approx((d.mean() - half, d.mean() + half), abs=0.01)


# ---------------------------------------------------------------------------------------------
# the planner
# ---------------------------------------------------------------------------------------------
def test_attempts_needed_by_hand():
    # p1 = 0.5, p2 = 0.6: pbar = 0.55; (1.959964*sqrt(2*.55*.45) + 0.841621*sqrt(.25+.24))^2 / 0.01
    z_a, z_b = 1.959963985, 0.841621234
    n = (z_a * math.sqrt(2 * 0.55 * 0.45) + z_b * math.sqrt(0.25 + 0.24)) ** 2 / 0.01
    assert st.attempts_needed(0.5, 0.6) == math.ceil(n) == 388
    with pytest.raises(ValueError):
        st.attempts_needed(0.5, 0.5)


@pytest.mark.parametrize("p1,p2", [(0.5, 0.6), (0.2, 0.4), (0.1, 0.15), (0.7, 0.9), (0.05, 0.5), (0.3, 0.25)])
def test_attempts_needed_matches_statsmodels(p1, p2):
    from statsmodels.stats.proportion import power_proportions_2indep, samplesize_proportions_2indep_onetail

    n = st.attempts_needed(p1, p2)
    want = samplesize_proportions_2indep_onetail(p1 - p2, p2, 0.8, alpha=0.05)
    assert n == math.ceil(want - 1e-9)
    # and the exact-normal power (both tails) reaches 80% at n, not at n - 1
    power = lambda m: power_proportions_2indep(p1 - p2, p2, m, alpha=0.05, return_results=False)  # noqa: E731
    assert power(n) >= 0.8 > power(n - 1)


def test_cohens_table_through_the_same_normal_approximation():
    # Cohen, "A Power Primer" (Psychological Bulletin 112(1), 1992), Table 2: the sample size per
    # group for a difference between proportions at alpha = .05 (two-sided), power .80 is 392, 63
    # and 25 for the effect sizes h = .2, .5, .8 (h = 2 asin sqrt p1 - 2 asin sqrt p2). On the
    # arcsine scale the variance is 1/n, so the same normal approximation reads
    # n = 2 (z_{1-alpha/2} + z_power)^2 / h^2; statsmodels' NormalIndPower agrees.
    from statsmodels.stats.power import NormalIndPower

    z = 1.959963985 + 0.841621234
    for h, table in [(0.2, 392), (0.5, 63), (0.8, 25)]:
        n = 2 * z * z / h / h
        assert round(n) == table
        assert NormalIndPower().solve_power(effect_size=h, alpha=0.05, power=0.8) == pytest.approx(n, rel=1e-3)
    # and our rates-based formula is close to the arcsine one for moderate rates: p = .5 vs .6
    h = 2 * math.asin(math.sqrt(0.6)) - 2 * math.asin(math.sqrt(0.5))
    assert st.attempts_needed(0.5, 0.6) == pytest.approx(2 * z * z / h / h, rel=0.01)


def test_plan_spreads_attempts_over_tasks():
    p = st.plan(0.1, baseline=0.55, tasks=25)
    assert p["rates"] == pytest.approx((0.5, 0.6))
    assert p["attempts_per_config"] == 388 and p["attempts_per_task"] == 16 and p["attempts_per_config_rounded"] == 400
    # rates are kept inside [0, 1]
    assert st.plan(0.3, baseline=0.95)["rates"] == pytest.approx((0.7, 1.0))
    with pytest.raises(ValueError):
        st.plan(0.0)


# ---------------------------------------------------------------------------------------------
# the paired planner (McNemar)
# ---------------------------------------------------------------------------------------------
def test_pairs_needed_by_hand():
    # Connor (1987): delta = 0.1, pd = 0.2: (1.959964 sqrt(.2) + 0.841621 sqrt(.2 - .01))^2 / .01
    z_a, z_b = 1.959963985, 0.841621234
    n = (z_a * math.sqrt(0.2) + z_b * math.sqrt(0.19)) ** 2 / 0.01
    assert st.pairs_needed(0.1, 0.2) == math.ceil(n) == 155
    assert st.pairs_needed(-0.1, 0.2) == 155  # the sign of the difference does not matter
    # with every pair discordant the paired test is no better than... the sign test on all pairs
    assert st.pairs_needed(0.2, 1.0) == math.ceil((z_a + z_b * math.sqrt(0.96)) ** 2 / 0.04)
    for bad in ((0.3, 0.2), (0.0, 0.2), (0.1, 1.2)):
        with pytest.raises(ValueError):
            st.pairs_needed(*bad)


@pytest.mark.parametrize("n,p10,p01", [(12, 0.4, 0.05), (30, 0.3, 0.1), (25, 0.25, 0.05), (40, 0.2, 0.15)])
def test_exact_mcnemar_power_equals_enumerating_outcomes_with_scipy(n, p10, p01):
    from scipy.stats import binomtest, multinomial

    want = sum(multinomial.pmf([b, c, n - b - c], n, [p10, p01, 1 - p10 - p01])
               for b in range(n + 1) for c in range(n + 1 - b)
               if b + c and binomtest(b, b + c, 0.5).pvalue <= 0.05)
    assert st.mcnemar_exact_power(n, p10, p01) == pytest.approx(want, abs=1e-12)


@pytest.mark.parametrize("d,pd", [(0.1, 0.2), (0.2, 0.4), (0.15, 0.25)])
def test_exact_pairs_reach_the_power_the_approximation_misses(d, pd):
    p10, p01 = (pd + d) / 2, (pd - d) / 2
    approx, exact = st.pairs_needed(d, pd), st.pairs_needed_exact(d, pd)
    assert exact > approx  # the exact test is conservative
    assert st.mcnemar_exact_power(exact, p10, p01) >= 0.8
    assert all(st.mcnemar_exact_power(n, p10, p01) < 0.8 for n in range(approx, exact))
    # and the paired design needs far fewer attempts than the unpaired one at the same rates
    assert exact < st.attempts_needed(0.5 - d / 2, 0.5 + d / 2)


def test_plan_adds_the_paired_design_when_the_discordant_share_is_given():
    p = st.plan(0.1, tasks=25, discordant=0.2)
    assert p["paired"]["pairs"] == 168 and p["paired"]["pairs_approximation"] == 155
    assert p["paired"]["pairs_per_task"] == 7
    assert st.plan(0.1)["paired"] is None
