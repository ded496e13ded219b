"""The best estimate the physics allows next to a dropout: a fixed-interval Kalman smoother.

Model (``inverse.kalman.augmented_model``): the quarter vehicle driven by the track, the track
the output of the German-spectrum shaping filter at the speed, the accelerometer bias a random
walk, white sensor noise of the IMU's variance; discretised exactly at the IMU period. The
forward Kalman filter takes every sample it has and skips the missing ones (a dropout: the
prediction only, the covariance grows), the backward RTS pass brings every later sample back.
Within the model the smoothed track E[u | all samples] is the Bayes-optimal estimate (a
Gaussian conditional mean): its D1 band, E[D1 u | all samples], has the smallest mean square D1
error any estimator from the same data can have, at every output. Two measurements:

- tracks drawn from the model itself (Monte Carlo over the prior: the smoother is exactly
  optimal there), with the pipeline (model fill, the default) on the same samples;
- the simulator's runs with defects (table (e)'s eight places), where the model is only the
  stationary approximation of the real track (defects, 1-200 m synthesis band) and sensor
  (bias, scale error, chip filter, clock drift).

Score, as ``score.near``: the D1 error of the outputs within 50 m of the dropout (no output
inside it), the truth band-passed on distance at 0.25 m.

Usage: python benchmarks/bench_gap_baseline.py [--draws 40] [--gap 0.2] [--hold 0,0.5,1,inf]
"""

from __future__ import annotations

import argparse
import functools
import itertools

import numpy as np

from railgsa_ros.imu import accel_covariance, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.kalman import U_INDEX, augmented_model
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.inverse.score import band_distance, reconstruct
from railgsa_ros.scenario import run_scenario
from railgsa_ros.vehicle import VehicleParams

RADIUS_M = 50.0
DX_M = 0.25
INITIAL_BIAS_STD = 0.05  # m/s^2: prior of the bias at the start (a few mg, gravity removed)


class GapSmoother:
    """Time-varying Kalman filter + RTS smoother over T samples with a missing-sample mask.

    ``observed`` (T,) bool; the covariances (and so the gains) depend on the mask only, so they
    are computed once and applied to a batch of records ``smooth(y (N, T)) -> u (N, T)``.
    """

    def __init__(self, theta: np.ndarray, speed_mps: float, noise_var: float, rate_hz: float,
                 observed: np.ndarray, av: float = InversionConfig().track_spectrum_av,
                 bias_walk: float = InversionConfig().bias_walk_mps2) -> None:
        phi, q, c = (m[0] for m in augmented_model(theta, speed_mps, av, bias_walk,
                                                   1.0 / rate_hz))
        self.phi, self.q, self.c = phi, q, c[0]
        self.observed = np.asarray(observed, bool)
        n = phi.shape[0]
        self.p0 = self.stationary()
        t_len = self.observed.size
        self.gain = np.zeros((t_len, n))
        self.smoother = np.zeros((t_len, n, n))
        p_pred = self.p0
        for k in range(t_len):
            if self.observed[k]:
                pc = p_pred @ self.c
                gain = pc / (self.c @ pc + noise_var)
                p_filt = p_pred - np.outer(gain, pc)
                self.gain[k] = gain
            else:
                p_filt = p_pred
            p_next = phi @ p_filt @ phi.T + q
            p_next = 0.5 * (p_next + p_next.T)
            if k + 1 < t_len:  # J_k = P_k|k Phi^T P_k+1|k^-1
                self.smoother[k] = np.linalg.solve(p_next, phi @ p_filt).T
            p_pred = p_next

    def stationary(self) -> np.ndarray:
        """Prior covariance of the first state: the stationary one of vehicle and track (a
        discrete Lyapunov fixed point), the bias INITIAL_BIAS_STD, uncorrelated."""
        from scipy.linalg import solve_discrete_lyapunov

        n = self.phi.shape[0]
        s = slice(0, n - 1)
        p = np.zeros((n, n))
        p[s, s] = solve_discrete_lyapunov(self.phi[s, s], self.q[s, s])
        p[-1, -1] = INITIAL_BIAS_STD ** 2
        return 0.5 * (p + p.T)

    def smooth(self, y: np.ndarray, row: np.ndarray | None = None) -> np.ndarray:
        """Smoothed row @ state (N, T) from measurements y (N, T) m/s^2 (values at missing
        samples are ignored); row (7,) None: the track u (m); ``self.c``: the acceleration
        with its bias (m/s^2)."""
        y = np.atleast_2d(y)
        if row is None:
            row = np.eye(self.phi.shape[0])[U_INDEX]
        t_len = y.shape[1]
        filt = np.zeros((t_len, y.shape[0], self.phi.shape[0]))
        x = np.zeros((y.shape[0], self.phi.shape[0]))
        for k in range(t_len):
            if self.observed[k]:
                x = x + np.outer(y[:, k] - x @ self.c, self.gain[k])
            filt[k] = x
            x = x @ self.phi.T
        out = np.zeros((y.shape[0], t_len))
        xs = filt[-1]
        out[:, -1] = xs @ row
        for k in range(t_len - 2, -1, -1):
            xs = filt[k] + (xs - filt[k] @ self.phi.T) @ self.smoother[k].T
            out[:, k] = xs @ row
        return out

    def draw(self, count: int, rng: np.random.Generator, noise_var: float
             ) -> tuple[np.ndarray, np.ndarray]:
        """``count`` records from the model itself: (track u (N, T) m, measurement y (N, T))."""
        n, t_len = self.phi.shape[0], self.observed.size
        w, v = np.linalg.eigh(self.q)
        q_half = v * np.sqrt(np.clip(w, 0.0, None))
        w0, v0 = np.linalg.eigh(self.p0)
        x = rng.standard_normal((count, n)) @ (v0 * np.sqrt(np.clip(w0, 0.0, None))).T
        u, y = np.zeros((count, t_len)), np.zeros((count, t_len))
        for k in range(t_len):
            u[:, k] = x[:, U_INDEX]
            y[:, k] = x @ self.c + np.sqrt(noise_var) * rng.standard_normal(count)
            x = x @ self.phi.T + rng.standard_normal((count, n)) @ q_half.T
        return u, y


def d1_errors(chain: np.ndarray, truth: np.ndarray, est_chain: np.ndarray, est_d1: np.ndarray,
              centre_m: float) -> np.ndarray:
    """D1 errors (m) at the 0.25 m grid points within RADIUS_M of centre_m that have an
    output within DX_M / 2 (``score.near``'s rule); truth (m) at ``chain`` is band-passed here,
    est_d1 is already the D1 output at est_chain (increasing)."""
    x = np.arange(chain[0], chain[-1], DX_M)
    truth_d1 = band_distance(np.interp(x, chain, truth), DX_M)
    j = np.clip(np.searchsorted(est_chain, x), 1, est_chain.size - 1)
    covered = np.minimum(np.abs(x - est_chain[j - 1]), np.abs(est_chain[j] - x)) <= DX_M / 2
    win = covered & (np.abs(x - centre_m) <= RADIUS_M)
    return np.interp(x[win], est_chain, est_d1) - truth_d1[win]


def smoothed_d1(chain: np.ndarray, u_s: np.ndarray) -> np.ndarray:
    """D1 of a smoothed track (m) on distance, back at the samples' chainage."""
    x = np.arange(chain[0], chain[-1] + DX_M, DX_M)
    return np.interp(chain, x, band_distance(np.interp(x, chain, u_s), DX_M))


def model_monte_carlo(draws: int, gap_s: float, speed: float = 20.0, rate: float = 1000.0,
                      duration: float = 30.0, seed: int = 7) -> dict[str, np.ndarray]:
    """Largest |D1 error| (m) within 50 m of a gap in the middle, per draw: smoother and
    pipeline (default config, model fill) on tracks drawn from the smoother's own model."""
    theta = VehicleParams().as_array()
    noise = accel_covariance(imu_spec('adxl355'))
    t_len = round(duration * rate)
    t = np.arange(t_len) / rate
    at = duration / 2
    observed = ~((t >= at) & (t < at + gap_s))
    smoother = GapSmoother(theta, speed, noise, rate, observed)
    u, y = smoother.draw(draws, np.random.default_rng(seed), noise)
    u_s = smoother.smooth(y)
    chain = speed * t
    stamps = np.round(t * 1e9).astype(np.int64) + 10 ** 18
    cfg = InversionConfig(rate_hz=rate)
    res = {'model tracks: smoother': [], 'model tracks: pipeline (model fill)': []}
    for i in range(draws):
        res['model tracks: smoother'].append(np.max(np.abs(d1_errors(
            chain, u[i], chain[observed], smoothed_d1(chain, u_s[i])[observed], speed * at))))
        pipe = InversionPipeline(cfg, theta, noise_variance=noise)
        out = Output.concat([pipe.push(stamps[observed], y[i, observed] + cfg.gravity_mps2,
                                       speed), pipe.flush()])
        res['model tracks: pipeline (model fill)'].append(np.max(np.abs(d1_errors(
            chain, u[i], out.chainage_m, out.u_m, speed * at))))
    return {k: np.array(v) for k, v in res.items()}


def simulator_places(gap_s: float, holds: tuple[float, ...], window_s: float = 12.0
                     ) -> dict[str, np.ndarray]:
    """Largest |D1 error| (m) within 50 m of a dropout at table (e)'s eight places (ADXL355
    model, 20 m/s, 8 mm dip): the smoother on every sample within window_s of the gap (the
    information about the gap beyond is nil), the pipeline with its model fill (default), and
    the pipeline with the smoother's fill E[a | samples up to hold s after the gap] for each
    hold (0: the Kalman prediction across the gap; inf: every sample)."""
    cfg = InversionConfig()
    res: dict[str, list[float]] = {'smoother': [], 'pipeline (model fill)': []}
    res.update({f'pipeline, smoother fill, hold {h:g} s': [] for h in holds})
    for seed, at in itertools.product((1, 3), (10.0, 15.0, 20.0, 25.0)):
        run = run_scenario('german-low', 20.0, 40.0, None,
                           imu_spec('adxl355', dropout_fraction=0), seed=seed,
                           defects='dip@400:len=6:depth=8e-3')
        t = run.t_true_s - run.t_true_s[0]
        gap = (t >= at) & (t < at + gap_s)
        centre = float(np.interp(at, t, run.chainage_m))
        a = vertical(run.accel, 'z')
        win = np.abs(t - at) <= window_s
        y = (a - cfg.gravity_mps2)[win]
        smoother = functools.partial(GapSmoother, VehicleParams().as_array(), 20.0,
                                     run.accel_covariance, run.rate_hz)

        full = smoother(~gap[win])
        chain_w = run.chainage_m[win]
        keep_w = ~gap[win]
        res['smoother'].append(np.max(np.abs(d1_errors(
            run.chainage_m, run.truth_u_m, chain_w[keep_w],
            smoothed_d1(chain_w, full.smooth(y)[0])[keep_w], centre))))
        chain, out = reconstruct(run, None, ~gap)
        res['pipeline (model fill)'].append(np.max(np.abs(d1_errors(
            run.chainage_m, run.truth_u_m, chain, out.u_m, centre))))
        for hold in holds:
            s = full if np.isinf(hold) else smoother(keep_w & (t[win] < at + gap_s + hold))
            filled = a.copy()
            filled[gap] = s.smooth(y, s.c)[0][gap[win]] + cfg.gravity_mps2
            pipe = InversionPipeline(cfg.with_(rate_hz=run.rate_hz),
                                     noise_variance=run.accel_covariance)
            out = Output.concat([pipe.push(run.stamps_ns, filled, run.speed_mps), pipe.flush()])
            out_chain = out.chainage_m + run.chainage_m[0]
            res[f'pipeline, smoother fill, hold {hold:g} s'].append(np.max(np.abs(d1_errors(
                run.chainage_m, run.truth_u_m, out_chain[~gap], out.u_m[~gap], centre))))
    return {k: np.array(v) for k, v in res.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--draws', type=int, default=40)
    parser.add_argument('--gap', type=float, default=0.2, help='s')
    parser.add_argument('--hold', default='0,0.25,0.5,1,inf', help='s, comma-separated')
    args = parser.parse_args()
    holds = tuple(float(h) for h in args.hold.split(','))
    res = model_monte_carlo(args.draws, args.gap)
    res.update(simulator_places(args.gap, holds))
    for name, big in res.items():
        print(f'{name}: max within 50 m mean {big.mean() * 1e3:.3f} mm, worst '
              f'{big.max() * 1e3:.3f} mm, P(<= 0.3 mm) {np.mean(big <= 3e-4):.2f}')


if __name__ == '__main__':
    main()
