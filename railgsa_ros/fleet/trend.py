"""Depth of one defect over time: weighted least-squares line, and when it reaches a limit.

The fit is d(t) = a + b (t - t0) with weights 1 / sigma_i^2 (sigma_i: the stated depth
uncertainty of pass i); the covariance of (a, b) is (A^T W A)^-1, scaled up by the reduced
chi-square when the points scatter more than their sigmas say (Birge ratio; never scaled down).
The projected date of reaching a limit L is where the fitted line crosses it; its interval is
where the pointwise confidence band (z = 1.96) crosses it: earliest where the upper edge does,
latest where the lower edge does (open ended when the slope is not significantly positive).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

Z95 = 1.96


@dataclass(frozen=True)
class Trend:
    """Fitted depth a (m) at t0 (days), rate b (m/day), covariance (2, 2) of (a, b), reduced
    chi-square (NaN with two points) and the number of points."""

    t0_days: float
    depth_m: float
    rate_m_per_day: float
    cov: np.ndarray
    chi2_red: float
    points: int

    @property
    def rate_se(self) -> float:
        """Standard error of the rate (m/day)."""
        return float(np.sqrt(self.cov[1, 1]))

    def at(self, t_days: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Fitted depth (m) and its standard deviation (m) at times t (days)."""
        dt = np.asarray(t_days, dtype=float) - self.t0_days
        c = self.cov
        var = c[0, 0] + 2 * dt * c[0, 1] + dt * dt * c[1, 1]
        return self.depth_m + self.rate_m_per_day * dt, np.sqrt(np.maximum(var, 0.0))


def fit_trend(t_days: np.ndarray, depth_m: np.ndarray, sigma_m: np.ndarray) -> Trend | None:
    """Weighted least-squares line through (t, depth) with SDs sigma (module docstring); None
    with fewer than two distinct times."""
    t = np.asarray(t_days, dtype=float)
    d = np.asarray(depth_m, dtype=float)
    w = 1.0 / np.asarray(sigma_m, dtype=float) ** 2
    if np.unique(t).size < 2:
        return None
    t0 = float(np.sum(w * t) / np.sum(w))
    design = np.column_stack([np.ones_like(t), t - t0])
    normal = design.T @ (w[:, None] * design)
    cov = np.linalg.inv(normal)
    coef = cov @ (design.T @ (w * d))
    chi2_red = float('nan')
    if t.size > 2:
        chi2_red = float(np.sum(w * (d - design @ coef) ** 2) / (t.size - 2))
        cov = cov * max(1.0, chi2_red)
    return Trend(t0, float(coef[0]), float(coef[1]), cov, chi2_red, int(t.size))


def crossing(trend: Trend, limit_m: float, now_days: float, z: float = Z95
             ) -> tuple[float, float, float]:
    """(central, earliest, latest) first time (days) at or after ``now_days`` when the fitted
    depth, the upper and the lower edge of its confidence band reach ``limit_m``; inf when that
    never happens (latest is inf unless the rate is significantly positive at z)."""
    a, b, c = trend.depth_m, trend.rate_m_per_day, trend.cov
    gap, now = limit_m - a, now_days - trend.t0_days
    # band edge = limit <=> (gap - b x)^2 = z^2 (c00 + 2 c01 x + c11 x^2), x = t - t0
    roots = np.roots([b * b - z * z * c[1, 1], -2 * (gap * b + z * z * c[0, 1]),
                      gap * gap - z * z * c[0, 0]])
    roots = np.sort(roots[np.abs(roots.imag) < 1e-9 * (1 + np.abs(roots.real))].real)
    tol = 1e-9 + 1e-6 * abs(limit_m)

    def first(edge: float) -> float:
        """First x >= now where a + b x + edge * z * sd(x) reaches the limit."""
        if a + b * now + edge * z * _sd(c, now) >= limit_m:
            return now
        hits = [x for x in roots if x > now and abs(a + b * x + edge * z * _sd(c, x) - limit_m)
                < tol]
        return min(hits, default=np.inf)

    central = now if a + b * now >= limit_m else (gap / b if b > 0 else np.inf)
    return (trend.t0_days + central, trend.t0_days + first(1.0),
            trend.t0_days + first(-1.0))


def _sd(c: np.ndarray, x: float) -> float:
    """SD of the fitted line at x (days from t0)."""
    return float(np.sqrt(max(c[0, 0] + 2 * x * c[0, 1] + x * x * c[1, 1], 0.0)))
