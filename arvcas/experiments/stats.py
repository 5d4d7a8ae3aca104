"""Interval estimates for Monte Carlo summaries, NumPy and the standard library only.

- :func:`mean_ci`: the mean of finite values with its Student-t confidence interval
  (``mean +- t_{(1+level)/2, n-1} sd / sqrt(n)``). Each value is itself a mean over 1000 controller
  samples of one run, and runs are independent draws, so the central limit theorem makes the
  t-interval appropriate for the run counts used here (n >= 30; it is exact for normal data).
- :func:`paired_ci`: the mean of paired differences ``a_i - b_i`` (same draw ``i``), t-interval.
- :func:`welch_ci`: unpaired difference of means (Welch-Satterthwaite degrees of freedom), for two
  Monte Carlo files that do not share their draws.
- :func:`median_ci`: the median of finite values with the distribution-free interval of the sign
  test (order statistics ``x_(k)``, ``x_(n+1-k)`` with ``P(Binom(n, 1/2) < k) <= (1 - level)/2``):
  unlike the t-interval it is not moved by a few extreme runs (a run that nearly diverges).
- :func:`wilson`: a binomial proportion (the failure rate) with its Wilson score interval, which
  stays inside [0, 1] and is informative at 0 failures (unlike the normal approximation).
- :func:`t_quantile`: Student-t quantile for real ``df > 0`` by bisection on the CDF, itself the
  regularised incomplete beta function by Lentz's continued fraction (tested against SciPy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

__all__ = ["Interval", "t_cdf", "t_quantile", "mean_ci", "median_ci", "paired_ci", "paired_median_ci", "welch_ci",
           "wilson", "LEVEL"]

LEVEL = 0.95


@dataclass(frozen=True)
class Interval:
    """An estimate with its two-sided interval at ``level``; ``n`` values used (NaN estimate if none)."""

    estimate: float
    lo: float
    hi: float
    n: int
    level: float = LEVEL
    sd: float = float("nan")

    @property
    def excludes_zero(self) -> bool:
        """True when the interval lies strictly on one side of 0 (the sign is certain at ``level``)."""
        return bool(self.lo > 0 or self.hi < 0)


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz)."""
    tiny, eps = 1e-300, 1e-16
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    f = d
    for m in range(1, 10000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        f *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        f *= delta
        if abs(delta - 1.0) < eps:
            return f
    raise ArithmeticError(f"incomplete beta: continued fraction did not converge (a={a}, b={b}, x={x})")


def _betainc(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta I_x(a, b), 0 <= x <= 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    ln = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    front = math.exp(ln)
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


def t_cdf(t: float, df: float) -> float:
    """CDF of Student's t with ``df > 0`` degrees of freedom (real)."""
    if not df > 0:
        raise ValueError(f"t_cdf: df must be > 0, got {df}")
    tail = 0.5 * _betainc(df / 2.0, 0.5, df / (df + t * t))
    return 1.0 - tail if t > 0 else tail


def t_quantile(p: float, df: float) -> float:
    """Quantile of Student's t (``0 < p < 1``, real ``df > 0``), to ~1e-12 relative."""
    if not 0.0 < p < 1.0:
        raise ValueError(f"t_quantile: p must be in (0, 1), got {p}")
    if p == 0.5:
        return 0.0
    if p < 0.5:
        return -t_quantile(1.0 - p, df)
    hi = 1.0
    while t_cdf(hi, df) < p:
        hi *= 2.0
    lo = 0.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if t_cdf(mid, df) < p:
            lo = mid
        else:
            hi = mid
        if hi - lo <= 1e-13 * hi:
            break
    return 0.5 * (lo + hi)


def _finite(x) -> np.ndarray:
    x = np.asarray(x, dtype=float).ravel()
    return x[np.isfinite(x)]


def mean_ci(x, level: float = LEVEL) -> Interval:
    """Mean of the finite entries of ``x`` with its t-interval (NaN bounds if fewer than 2)."""
    v = _finite(x)
    n = v.size
    if n == 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0, level)
    m = float(np.mean(v))
    if n < 2:
        return Interval(m, float("nan"), float("nan"), n, level)
    sd = float(np.std(v, ddof=1))
    half = t_quantile(0.5 + level / 2.0, n - 1) * sd / math.sqrt(n)
    return Interval(m, m - half, m + half, n, level, sd)


def median_ci(x, level: float = LEVEL) -> Interval:
    """Median of the finite entries of ``x`` with the sign-test (order-statistic) interval, whose
    coverage is at least ``level`` for any continuous distribution (NaN bounds when n is too small)."""
    v = np.sort(_finite(x))
    n = v.size
    if n == 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0, level)
    med = float(np.median(v))
    alpha2 = (1.0 - level) / 2.0
    # largest k >= 1 with P(B <= k - 1) <= alpha/2, B ~ Binom(n, 1/2); exact integer arithmetic
    total, term, cdf, k = 2**n, 1, 0, 0  # term = C(n, i)
    for i in range(n // 2 + 1):
        cdf += term
        if cdf / total > alpha2:
            break
        k = i + 1
        term = term * (n - i) // (i + 1)
    if k == 0:
        return Interval(med, float("nan"), float("nan"), n, level)
    return Interval(med, float(v[k - 1]), float(v[n - k]), n, level)


def _paired_differences(a, b, who: str) -> np.ndarray:
    """``a_i - b_i`` of two samples of the same shape (flattened); ``who`` names the caller in the error."""
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    if a.shape != b.shape:
        raise ValueError(f"{who}: a and b must pair up, got shapes {a.shape} and {b.shape}")
    return a - b


def paired_median_ci(a, b, level: float = LEVEL) -> Interval:
    """Median of ``a_i - b_i`` over the pairs where both are finite, sign-test interval."""
    return median_ci(_paired_differences(a, b, "paired_median_ci"), level)


def paired_ci(a, b, level: float = LEVEL) -> Interval:
    """Mean of ``a_i - b_i`` over the pairs where both are finite, t-interval (same draw i)."""
    return mean_ci(_paired_differences(a, b, "paired_ci"), level)


def welch_ci(a, b, level: float = LEVEL) -> Interval:
    """Difference of means mean(a) - mean(b) of independent samples, Welch's t-interval."""
    va, vb = _finite(a), _finite(b)
    na, nb = va.size, vb.size
    if na < 2 or nb < 2:
        d = float(np.mean(va) - np.mean(vb)) if na and nb else float("nan")
        return Interval(d, float("nan"), float("nan"), min(na, nb), level)
    sa, sb = np.var(va, ddof=1) / na, np.var(vb, ddof=1) / nb
    se = math.sqrt(sa + sb)
    d = float(np.mean(va) - np.mean(vb))
    if se == 0:
        return Interval(d, d, d, min(na, nb), level, 0.0)
    df = (sa + sb) ** 2 / (sa**2 / (na - 1) + sb**2 / (nb - 1))
    half = t_quantile(0.5 + level / 2.0, df) * se
    return Interval(d, d - half, d + half, min(na, nb), level, se)


def wilson(k: int, n: int, level: float = LEVEL) -> Interval:
    """Proportion k/n with its Wilson score interval."""
    if n <= 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0, level)
    if not 0 <= k <= n:
        raise ValueError(f"wilson: need 0 <= k <= n, got k={k}, n={n}")
    z = NormalDist().inv_cdf(0.5 + level / 2.0)
    p = k / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    lo = 0.0 if k == 0 else max(0.0, centre - half)
    hi = 1.0 if k == n else min(1.0, centre + half)
    return Interval(p, lo, hi, n, level)
