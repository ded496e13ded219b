"""Vehicle parameters from a reference run whose geometry is known (issue 12 item 6).

The paper's conclusion is to know k_s precisely. Which parameters the acceleration identifies
follows from the GSA of the inverse scenario (docs/uq.md): total Sobol' indices 0.77 (k_s), 0.24
(c) and 0.001 (k_us) at CoV 0.1, so k_s and c are estimated (``IDENTIFIABLE``) and k_us stays
nominal. ``calibrate`` reports the condition number of the Fisher information of any requested
set (scaled to relative parameters), so an unidentifiable choice shows as a large number.

Model: the band reconstruction u(theta) (the streaming pipeline, a bank of parameter sets) on a
stretch against the reference profile band-passed on distance the same way (``score``). Residual
r(p) = u(theta(p)) - u_ref at the reconstruction's samples, p = ln(theta / nominal) of the chosen
parameters. Gauss-Newton with a Gaussian prior on p (from the uncertainty law: std sigma / mu)
and forward-difference Jacobian columns computed in the same bank run; the posterior (Laplace)
covariance is (J^T J / s^2 + P0^-1)^-1 with s^2 the residual variance times the residual's
integrated autocorrelation (the samples of a band-limited residual are not independent).

The reference's registration is a nuisance parameter of the same fit: a chainage shift (m,
prior std SHIFT_PRIOR_M) of the reference, its Jacobian column minus the reference's slope. A
survey is rarely registered to better than a metre, and without it the fit bent the vehicle to
the shift (0.1 m made k_s 8 SD and c 16 SD off; measured). The reference is read through a
cubic spline of its band (a linear interpolation of the DX_M grid left ~1e-6 m, a third of the
noise-free residual, for k_us to absorb).

The sensor delay tau (the chip filter's group delay, ``InversionConfig.sensor_delay_s``) can be
a third nuisance parameter (``fit_delay``, prior std DELAY_PRIOR_S around the configured delay):
the output advanced by tau more moves by v tau along the track, so its Jacobian column is
v du/dx of the reconstruction. At constant speed that column is -v times the registration's:
a delay and a registration shift are the same thing there, and only speed changes or a
registered reference (a small ``shift_prior_m``) tell them apart. ``Calibration.delay_shift_corr``
says how far they were told apart (near -1 or +1: not at all; the prior then decides).

Model discrepancy (Kennedy-O'Hagan): even the true parameters leave an error the band's terms do
not hold (e.g. the chainage shift of a drifting sensor clock). ``discrepancy_std`` measures it on
the same stretch from the band of the calibrated run (posterior law + sensor terms): the mean
square of (band mean - reference) beyond the band's own mean variance, written to the
uncertainty file as ``discrepancy_std_m`` and added in variance by every band
(``uncertainty.terms``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.optimize import brentq
from scipy.stats import norm

from railgsa_ros.errors import InputError
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline, Output
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.inverse.score import band_distance
from railgsa_ros.uncertainty.stream import Band
from railgsa_ros.uq.distributions import Distribution
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

IDENTIFIABLE = ('k_s', 'c')
STEP = 1e-3  # relative finite-difference step of the Jacobian
ITERATIONS = 8
DX_M = 0.25  # grid of the band-passed reference, m
MARGIN_M = 50.0  # left out at both ends of the stretch (filter edges), m
MIN_CORRELATION = 0.8  # reference and reconstruction must agree this well before calibration
SHIFT_PRIOR_M = 2.0  # prior std of the reference's chainage shift (its registration), m
DELAY_PRIOR_S = 0.02  # prior std of a fitted sensor delay, s (chip filters: 0.4-80 ms)


@dataclass(frozen=True)
class Calibration:
    """Posterior of the calibrated parameters: names, mean (n,) and covariance (n, n) in physical
    units, the full theta (5,), the residual RMS before and after (m), the Fisher condition
    number, the correlation of reconstruction and reference before, and the points used."""

    names: tuple[str, ...]
    mean: np.ndarray
    covariance: np.ndarray
    theta: np.ndarray
    rmse_before_m: float
    rmse_after_m: float
    condition: float
    correlation: float
    points: int
    shift_m: float = 0.0  #: fitted chainage shift of the reference (its registration), m
    shift_sd_m: float = 0.0  #: its posterior std, m
    delay_s: float = float('nan')  #: fitted sensor delay, s (NaN: not fitted)
    delay_sd_s: float = float('nan')  #: its posterior std, s
    delay_shift_corr: float = float('nan')  #: posterior correlation of delay and shift

    def vehicle(self) -> VehicleParams:
        """The calibrated vehicle (posterior mean)."""
        return VehicleParams(*self.theta)

    def uncertainty(self) -> dict[str, dict[str, str | float]]:
        """The uncertainty-file ``parameters:`` entries: normal(mean, marginal std)."""
        std = np.sqrt(np.diag(self.covariance))
        return {n: {'dist': 'normal', 'mu': float(m), 'sigma': float(s)}
                for n, m, s in zip(self.names, self.mean, std, strict=True)}


def _reference_band(chainage_m: np.ndarray, u_m: np.ndarray, config: InversionConfig
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The reference profile band-passed on a DX_M grid: (x, u) m."""
    x = np.arange(chainage_m[0], chainage_m[-1], DX_M)
    return x, band_distance(np.interp(x, chainage_m, u_m), DX_M, config.band, config.band_order)


def _bank(stamps_ns, acc_z, speed, config, thetas) -> Output:
    pipe = InversionPipeline(config, thetas)
    return Output.concat([pipe.push(stamps_ns, acc_z, speed), pipe.flush()],
                         channels=len(thetas))


def _correlation_time(resid: np.ndarray) -> float:
    """Integrated autocorrelation (samples) of a residual, summed up to its first zero."""
    r = resid - resid.mean()
    spec = np.fft.rfft(r, 2 * r.size)
    acf = np.fft.irfft(np.abs(spec) ** 2)[:r.size]
    acf /= acf[0]
    stop = int(np.argmax(acf < 0)) or acf.size
    return float(max(1.0, 1.0 + 2.0 * acf[1:stop].sum()))


def calibrate(stamps_ns: np.ndarray, acc_z: np.ndarray, speed_mps: np.ndarray,
              reference: tuple[np.ndarray, np.ndarray], config: InversionConfig,
              vehicle: VehicleParams, prior: Mapping[str, Distribution],
              names: tuple[str, ...] = IDENTIFIABLE, fit_delay: bool = False,
              shift_prior_m: float = SHIFT_PRIOR_M) -> Calibration:
    """Calibrate ``names`` on the stretch covered by ``reference`` = (chainage (R,) m, u (R,) m),
    chainage counted from the first IMU sample (the pipeline's). IMU stamps (T,) ns, upward
    specific force (T,) m/s^2, speed (T,) m/s; prior: distributions of ``names`` (their mean
    and std define the Gaussian prior of the relative parameters); ``fit_delay``: also fit the
    sensor delay (s, >= 0) from ``config.sensor_delay_s``; ``shift_prior_m``: prior std of the
    reference's registration (m)."""
    missing = [n for n in names if n not in prior]
    if missing or not names:
        raise InputError(f'calibrate: no prior for {", ".join(missing) or "any parameter"}')
    x_ref, u_ref = _reference_band(*reference, config)
    spline = CubicSpline(x_ref, u_ref)
    slope = spline.derivative()
    nominal = vehicle.as_array()
    cols = [PARAM_NAMES.index(n) for n in names]
    n = len(names)
    means = np.array([prior[k].mean() for k in names])
    # q = (ln(theta / nominal) of the names, the reference's shift m[, the delay s]), its prior
    q0 = np.append(np.log(means / nominal[cols]), [0.0, config.sensor_delay_s][:1 + fit_delay])
    prior_prec = np.diag(np.concatenate([
        (means / np.array([prior[k].std() for k in names])) ** 2,
        [shift_prior_m ** -2, DELAY_PRIOR_S ** -2][:1 + fit_delay]]))
    q = q0.copy()
    for it in range(ITERATIONS + 1):
        thetas = np.tile(nominal, (n + 1, 1))
        thetas[:, cols] = nominal[cols] * np.exp(q[:n])
        thetas[1:, cols] *= np.exp(np.eye(n) * STEP)
        if fit_delay:
            q[n + 1] = max(q[n + 1], 0.0)  # a causal filter delays
            config = config.with_(sensor_delay_s=float(q[n + 1]))
        out = _bank(stamps_ns, acc_z, speed_mps, config, thetas)
        keep = ((out.chainage_m > x_ref[0] + MARGIN_M) & (out.chainage_m < x_ref[-1] - MARGIN_M)
                & np.all(np.isfinite(out.u_m), axis=0) & (out.quality != Quality.INVALID))
        if keep.sum() < 100:
            raise InputError('calibrate: the reference covers fewer than 100 valid '
                             f'reconstructed samples (reference {x_ref[0]:.0f}-{x_ref[-1]:.0f} m)')
        at = out.chainage_m[keep] + q[n]
        ref = spline(at)
        u = out.u_m[:, keep]
        resid = u[0] - ref
        if it == 0:
            before, corr = float(np.sqrt(np.mean(resid ** 2))), float(np.corrcoef(u[0], ref)[0, 1])
            if corr < MIN_CORRELATION:
                raise InputError(f'calibrate: the reference does not match the run '
                                 f'(correlation {corr:.2f} < {MIN_CORRELATION}); check the '
                                 'chainage offset')
        jac = np.column_stack([(u[1:] - u[0]).T / STEP, -slope(at)])  # (N, n + 1)
        if fit_delay:  # advanced tau more, the output moves v tau along the track
            v = np.interp(out.stamps_ns[keep], stamps_ns, np.abs(speed_mps))
            jac = np.column_stack([jac, v * np.gradient(u[0], out.chainage_m[keep])])
        s2 = np.mean(resid ** 2) * _correlation_time(resid)
        info = jac.T @ jac / s2
        hess = info + prior_prec
        grad = jac.T @ resid / s2 + prior_prec @ (q - q0)
        if it == ITERATIONS:
            break
        q = q - np.linalg.solve(hess, grad)
    cov_q = np.linalg.inv(hess)
    mean = nominal[cols] * np.exp(q[:n])
    theta = nominal.copy()
    theta[cols] = mean
    delay = {}
    if fit_delay:
        sd = np.sqrt(np.diag(cov_q)[n:])
        delay = {'delay_s': float(q[n + 1]), 'delay_sd_s': float(sd[1]),
                 'delay_shift_corr': float(cov_q[n, n + 1] / (sd[0] * sd[1]))}
    return Calibration(tuple(names), mean, cov_q[:n, :n] * np.outer(mean, mean), theta, before,
                       float(np.sqrt(np.mean(resid ** 2))), float(np.linalg.cond(info[:n, :n])),
                       corr, int(keep.sum()), float(q[n]), float(np.sqrt(cov_q[n, n])), **delay)


def discrepancy_std(band: Band, reference: tuple[np.ndarray, np.ndarray], config: InversionConfig,
                    quantiles: tuple[float, float]) -> float:
    """Model-discrepancy std d (m) over the reference stretch (margins left out, INVALID samples
    skipped; chainage as in ``calibrate``): the maximum-likelihood d of r_i ~ N(0, s_i^2 + d^2),
    r = band mean - the band-passed reference, s the band's Gaussian-equivalent std
    (upper - lower) / (z_upper - z_lower) at ``quantiles``. The band's variance is uneven (the
    delay term is largest at defects), so the moment estimate sqrt(mean r^2 - mean s^2) is
    dominated by a few wide samples and can say 0 where the band misses most of the others;
    the likelihood weighs each sample by its own variance. 0 when the band already holds r."""
    x_ref, u_ref = _reference_band(*reference, config)
    keep = ((band.chainage_m > x_ref[0] + MARGIN_M) & (band.chainage_m < x_ref[-1] - MARGIN_M)
            & np.isfinite(band.mean_m) & np.isfinite(band.lower_m) & np.isfinite(band.upper_m))
    if band.quality is not None:
        keep &= band.quality != Quality.INVALID
    if keep.sum() < 100:
        raise InputError('calibrate: fewer than 100 valid band samples on the reference stretch')
    # cubic: a linear interpolation of the DX_M grid alone leaves ~1e-6 m at D1's short waves
    r2 = (band.mean_m[keep] - CubicSpline(x_ref, u_ref)(band.chainage_m[keep])) ** 2
    s2 = ((band.upper_m[keep] - band.lower_m[keep]) /
          float(np.diff(norm.ppf(quantiles))[0])) ** 2

    def score(d2: float) -> float:  # d/d(d^2) of the log-likelihood, decreasing near its root
        return float(np.sum(r2 / (s2 + d2) ** 2 - 1.0 / (s2 + d2)))

    if score(0.0) <= 0.0:
        return 0.0
    return float(np.sqrt(brentq(score, 0.0, float(r2.max()))))  # score < 0 beyond max r^2
