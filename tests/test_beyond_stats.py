"""Interval estimates of arvcas.experiments.stats against SciPy (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sst

from arvcas.experiments.stats import mean_ci, paired_ci, t_cdf, t_quantile, welch_ci, wilson


@pytest.mark.parametrize("df", [1, 2, 3.5, 9, 29, 199, 999, 1e5])
@pytest.mark.parametrize("p", [0.975, 0.995, 0.6, 0.025, 0.5])
def test_t_quantile_and_cdf_match_scipy(df, p):
    q = t_quantile(p, df)
    assert q == pytest.approx(sst.t.ppf(p, df), rel=1e-9, abs=1e-12)
    assert t_cdf(q, df) == pytest.approx(sst.t.cdf(q, df), rel=1e-9)


def test_mean_ci_is_scipys_t_interval():
    x = np.random.default_rng(3).gamma(2.0, 1.5, 57)
    x[[4, 9]] = np.nan  # non-finite entries (diverged runs) are left out
    iv = mean_ci(x)
    v = x[np.isfinite(x)]
    lo, hi = sst.t.interval(0.95, v.size - 1, loc=v.mean(), scale=sst.sem(v))
    assert (iv.n, iv.estimate) == (55, pytest.approx(v.mean(), rel=1e-15))
    assert iv.lo == pytest.approx(lo, rel=1e-10) and iv.hi == pytest.approx(hi, rel=1e-10)
    assert mean_ci([1.0]).n == 1 and np.isnan(mean_ci([1.0]).lo)


def test_paired_and_welch_intervals_match_scipy():
    rng = np.random.default_rng(5)
    a = rng.normal(1.0, 1.0, 40)
    b = a + rng.normal(0.3, 0.1, 40)  # strongly paired: the paired interval is far narrower
    p = paired_ci(a, b)
    r = sst.ttest_rel(a, b).confidence_interval(0.95)
    assert (p.lo, p.hi) == (pytest.approx(r.low, rel=1e-10), pytest.approx(r.high, rel=1e-10))
    assert p.excludes_zero and p.hi < 0
    w = welch_ci(a, b)
    r = sst.ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
    assert (w.lo, w.hi) == (pytest.approx(r.low, rel=1e-9), pytest.approx(r.high, rel=1e-9))
    assert not w.excludes_zero  # unpaired, the same data cannot tell the sign
    with pytest.raises(ValueError, match="pair up"):
        paired_ci(a, b[:-1])


@pytest.mark.parametrize("k, n", [(0, 200), (3, 200), (100, 200), (200, 200), (1, 7)])
def test_wilson_matches_scipy(k, n):
    iv = wilson(k, n)
    r = sst.binomtest(k, n).proportion_ci(0.95, method="wilson")
    assert iv.estimate == k / n
    assert iv.lo == pytest.approx(r.low, abs=1e-12) and iv.hi == pytest.approx(r.high, abs=1e-12)
    assert 0.0 <= iv.lo <= iv.estimate <= iv.hi <= 1.0


@pytest.mark.parametrize("n", [5, 6, 9, 20, 57, 500])
def test_median_ci_is_the_sign_test_interval(n):
    from arvcas.experiments.stats import median_ci, paired_median_ci

    x = np.random.default_rng(n).standard_cauchy(n)  # heavy tails: the case it is for
    iv = median_ci(x)
    v = np.sort(x)
    # k = the number of order statistics cut from each end + 1, from SciPy's binomial CDF
    k = max((j for j in range(n + 1) if sst.binom.cdf(j - 1, n, 0.5) <= 0.025), default=0)
    assert iv.estimate == np.median(x)
    if k == 0:
        assert np.isnan(iv.lo) and np.isnan(iv.hi)
    else:
        assert (iv.lo, iv.hi) == (v[k - 1], v[n - k])
        assert sst.binom.cdf(k - 1, n, 0.5) <= 0.025 < sst.binom.cdf(k, n, 0.5)
    d = paired_median_ci(x, np.zeros(n))
    assert (d.estimate, d.n) == (iv.estimate, n)
