"""Accuracy of the inversion against ground truth and the exact-physics baseline of the same run.

(a) Paper mode: noise-free nominal vehicle, the paper's profile at 10 m/s, feedback (Eq. 7,
    K = 1000) with no band: relative error max|u_rec - u| / max|u| (target <= 1e-3).
(b) ADXL355 sensor model, German low profile plus an 8 mm cosine dip over 6 m, a 3 mm dipped joint
    and a 0.3 mm weld, 800 m at 10, 20 and 40 m/s, odometry speed: every method with its default
    parameters, scored on distance in D1 (score.score: both signals reach the score in D1 once,
    100 m left out at each end): RMSE (target <= 0.3 mm), correlation (>= 0.95) and peak error
    on the 8 mm dip (<= 0.5 mm). Baseline: FFT of the whole record divided by G(j w), D1-limited.
(c) Sensor delay: runs without dropouts of the chips at datasheet settings, simulated with
    their causal chip filter (adxl355@1000Hz at 20 m/s, bmi088@400Hz and bmi088@200Hz at
    30 m/s), and a BMI088-like bag written independently (the delay-free model, then a scipy
    4-pole 80 Hz Butterworth): D1 RMSE of the delay-free model of the same run, not compensated,
    compensated by the setting's datasheet delay and by the figure the presets gave before
    (the delay-compensated FIR's group delay: 5.25 ms ADXL355, 31.9 ms BMI088).
(d) Variable speed with stops: named speed profiles; D1 error on the stretches above 3 m/s (and
    10 m/s) of the per-speed time-domain band and of the chainage grid (time-domain pre-band,
    0.25 m grid, D1 on distance), both against the truth band-passed on distance.
(e) Dropouts of 0.05, 0.2 and 1 s at four places of two runs (ADXL355, 20 m/s): largest D1 error
    of the output samples within 50 m of the dropout (mean and worst of the eight, share of them
    within 0.3 mm) and RMS over the 100 m after it, for the model fill with its default hold
    (``gap_hold_s``), without the hold, a straight line (the old bridge) and a filter reset,
    beside the exact-physics baseline: the fixed-interval Kalman smoother on all samples
    (bench_gap_baseline.py, Bayes-optimal in the model), and the largest gap term of the band
    (``Output.gap_std_m``) within 50 m. (e2): 0.2 s dropouts on tracks drawn from the model.
(f) Parameter mismatch: true k_s +15 %, k_us -10 %, c -15 %, BMI088 model at 30 m/s, inverted
    with the nominal and with the true parameters, beside the FFT baseline with the true ones.
(g) Calibration on 500 m of a reference run (the mismatch of (f)): D1 error on the rest and the
    band before and after (benchmarks/bench_uq_calibration.py).
(h) Coverage of the total uncertainty band on ensembles drawn from the priors
    (benchmarks/bench_uq_coverage.py; a few minutes).
``--multirate`` adds the multirate band stage against the single-rate FIR on the runs of (b).

Usage: python benchmarks/bench_inverse_accuracy.py [--length 800] [--seed 1] [--multirate]
    [--tables abcdefgh]
"""

from __future__ import annotations

from dataclasses import replace
import itertools
from unittest import mock

from bench_gap_baseline import GapSmoother, d1_errors, model_monte_carlo, smoothed_d1
from bench_uq_calibration import calibration_table
from bench_uq_coverage import coverage_table
import numpy as np
from scipy import signal
from tables import header, run_options

from railgsa_ros.imu import antialias_fir, imu_spec
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.gapfill import GapFiller
from railgsa_ros.inverse.grid import ChainageGrid, GridOutput, grid_config
from railgsa_ros.inverse.pipeline import InversionPipeline, Output, vertical
from railgsa_ros.inverse.score import band_distance, exact_inverse, near, reconstruct, score
from railgsa_ros.inverse.sensor import sensor_delay_s
from railgsa_ros.scenario import run_scenario
from railgsa_ros.simulate import simulate
from railgsa_ros.speed_profile import parse_speed_profile
from railgsa_ros.track import paper_profile
from railgsa_ros.vehicle import VehicleParams

DIP = (300.0, 6.0)
DEFECTS = f'dip@{DIP[0]:g}:len={DIP[1]:g}:depth=8e-3,joint@450,weld@600'
METHODS = {'spectral (default)': {'method': 'spectral'}, 'feedback': {'method': 'feedback'},
           'kalman (live)': {'method': 'kalman'},
           'kalman + RTS smoother': {'method': 'kalman', 'smoother': True}}
PROFILES = {'braking 1.6 m/s^2 + stop': 'accel:0-26:26s,cruise:26:20s:ripple=0.5,'
                                        'brake:26-0:16s,stop:10s,accel:0-20:20s,cruise:20:15s',
            'station (preset)': 'station', 'stop-and-go (preset)': 'stop-and-go'}
MISMATCH = {'k_s': 1.15, 'k_us': 0.90, 'c': 0.85}


def paper_mode() -> float:
    """Relative error of the feedback inversion of the paper profile, noise-free, no band."""
    dt = 1e-3
    t = np.arange(0.0, 14.0, dt)
    u = paper_profile(10.0 * t)
    a_s, _ = simulate(u, dt, VehicleParams())
    cfg = InversionConfig(method='feedback', band='none', taper_s=0.0)
    out = InversionPipeline(cfg).push(np.round(t * 1e9).astype(np.int64),
                                      a_s + cfg.gravity_mps2, 10.0)
    return float(np.max(np.abs(out.u_m - u)) / np.max(np.abs(u)))


def d1(run, config: InversionConfig | None = None, **kw) -> float:
    """D1 RMSE (m) of the pipeline over a run (score.score, 100 m left out at each end)."""
    chain, out = reconstruct(run, config, **kw)
    return score(chain, out.u_m, run.chainage_m, run.truth_u_m).rmse


def baseline(run, speed: float, vehicle=None):
    base = exact_inverse(run.stamps_ns, vertical(run.accel, 'z'), speed, vehicle=vehicle)
    return score(run.chainage_m, base, run.chainage_m, run.truth_u_m, defect=DIP)


def methods_table(length: float, seed: int, multirate: bool) -> None:
    print('(b) ADXL355, German low + 8 mm dip / 3 mm joint / 0.3 mm weld, D1 on distance')
    header('v m/s', 'method', 'RMSE mm', 'corr', 'dip peak mm', '/ base', 'pass')
    rates = []
    for speed in (10.0, 20.0, 40.0):
        run = run_scenario('german-low', speed, length / speed, None, 'adxl355', seed=seed,
                           defects=DEFECTS)
        b = baseline(run, speed)
        for name, overrides in METHODS.items():
            multi = reconstruct(run, InversionConfig(**overrides))
            s = score(multi[0], multi[1].u_m, run.chainage_m, run.truth_u_m, defect=DIP)
            print(row(name, speed, s, b.rmse))
            if multirate:
                single = reconstruct(run, InversionConfig(**overrides, multirate=False))
                s1 = score(single[0], single[1].u_m, run.chainage_m, run.truth_u_m, defect=DIP)
                rates.append((speed, name, s1.rmse, s.rmse, *difference(single, multi)))
        print(row('exact baseline (FFT)', speed, b, b.rmse))
    if multirate:
        print('\n(b2) multirate band stage against the single-rate FIR, same runs')
        header('v m/s', 'method', 'RMSE single mm', 'RMSE multirate mm',
               'max diff mm', 'RMS diff mm')
        for speed, name, rmse1, rmse, big, rms in rates:
            print(f'| {speed:4.0f} | {name:<22} | {rmse1 * 1e3:8.4f} | {rmse * 1e3:8.4f} | '
                  f'{big * 1e3:9.5f} | {rms * 1e3:9.5f} |')


def row(name: str, speed: float, s, base_rmse: float) -> str:
    ok = s.rmse <= 0.3e-3 and s.correlation >= 0.95 and s.peak_error <= 0.5e-3
    return (f'| {speed:4.0f} | {name:<22} | {s.rmse * 1e3:8.4f} | {s.correlation:7.4f} | '
            f'{s.peak_error * 1e3:8.4f} | {s.rmse / base_rmse:6.2f} | {"yes" if ok else "no":4} |')


def difference(single, multi, margin_m: float = 100.0) -> tuple[float, float]:
    """Largest and RMS difference (m) of two reconstructions of the same samples."""
    chain = single[0]
    keep = (chain >= chain[0] + margin_m) & (chain <= chain[-1] - margin_m)
    diff = multi[1].u_m[keep] - single[1].u_m[keep]
    return float(np.max(np.abs(diff))), float(np.sqrt(np.mean(diff ** 2)))


def fir_delay_s(name: str) -> float:
    """The delay the presets gave before issue 22: the (N - 1) / 2 taps of the model's
    delay-compensated anti-alias FIR at 4 x its output rate."""
    spec = imu_spec(name)
    return (antialias_fir(spec, 4 * spec.output_rate_hz).size - 1) / 2 / (4 * spec.output_rate_hz)


def delay_table(length: float, seed: int) -> None:
    print('\n(c) sensor delay of a causal chip filter (no dropouts), D1 RMSE mm')
    header('sensor, v', 'datasheet delay ms', 'delay-free model', 'not compensated',
           'compensated (datasheet)', 'compensated (old preset: ms)', 'exact baseline')
    cases = (('adxl355@1000Hz', 'adxl355@1000Hz', 20.0, 1000.0),
             ('bmi088@400Hz', 'bmi088@400Hz', 30.0, 400.0),
             ('bmi088@200Hz', 'bmi088@200Hz', 30.0, 200.0),
             ('bmi088 model 400 Hz + scipy 80 Hz', 'bmi088@200Hz', 30.0, 400.0))
    for label, setting, speed, rate in cases:
        chip = setting.split('@')[0]  # its delay-free model at the same output rate
        free = run_scenario('german-low', speed, length / speed, None,
                            imu_spec(chip, output_rate_hz=rate, dropout_fraction=0), seed=seed,
                            defects=DEFECTS)
        if 'scipy' in label:  # written independently of the simulator's chip filter
            sos = signal.butter(4, 80.0, fs=free.rate_hz, output='sos')
            zi = signal.sosfilt_zi(sos)[:, :, None] * free.accel[0]
            run = replace(free, accel=signal.sosfilt(sos, free.accel, axis=0, zi=zi)[0])
        else:
            run = run_scenario('german-low', speed, length / speed, None,
                               imu_spec(setting, dropout_fraction=0), seed=seed,
                               defects=DEFECTS)
        tau, old = sensor_delay_s(setting), fir_delay_s(chip)
        cells = [d1(free), d1(run), d1(run, InversionConfig(sensor_delay_s=tau)),
                 d1(run, InversionConfig(sensor_delay_s=old)), baseline(run, speed).rmse]
        print(f'| {label}, {speed:g} m/s | {tau * 1e3:.2f} | '
              + ' | '.join(f'{c * 1e3:.4f}' for c in cells[:3])
              + f' | {cells[3] * 1e3:.4f} ({old * 1e3:.2f}) | {cells[4] * 1e3:.4f} |')


def variable_speed_table(seed: int) -> None:
    print('\n(d) variable speed with stops (ADXL355 model), D1 RMSE mm on distance')
    header('profile', 'length m', 'time-domain band > 3 m/s', 'grid + distance band > 3 m/s',
           'time-domain > 10 m/s', 'grid > 10 m/s', 'RMS difference > 3 m/s')
    for name, spec in PROFILES.items():
        prof = parse_speed_profile(spec)
        run = run_scenario('german-low', prof, prof.duration_s, None, 'adxl355', seed=seed,
                           defects='dip@700:len=6:depth=8e-3')
        dx = 0.25
        x = np.arange(run.chainage_m[0], run.chainage_m[-1], dx)
        truth = band_distance(np.interp(x, run.chainage_m, run.truth_u_m), dx)
        moving = np.concatenate([[True], np.diff(run.chainage_m) > 0])
        v = np.interp(x, run.chainage_m[moving], run.speed_mps[moving])
        inner = (x > x[0] + 100) & (x < x[-1] - 100)
        chain, out = reconstruct(run)
        on = np.concatenate([[True], np.diff(chain) > 0]) & np.isfinite(out.u_m)
        time_u = np.interp(x, chain[on], out.u_m[on])
        chain, out = reconstruct(run, grid_config(InversionConfig()))
        g = ChainageGrid()
        grid = GridOutput.concat([g.push(Output(out.stamps_ns, chain, out.u_m, out.quality,
                                                out.speed_mps)), g.flush()])
        grid_u = np.interp(x, grid.chainage_m, grid.u_m)  # NaN next to INVALID points
        inner &= np.isfinite(grid_u)  # both scored where the grid is not INVALID
        cells = []
        for vmin in (3.0, 10.0):
            keep = inner & (v > vmin)
            cells += [np.sqrt(np.mean((u - truth)[keep] ** 2)) for u in (time_u, grid_u)]
        keep = inner & (v > 3.0)
        cells.append(np.sqrt(np.mean((time_u - grid_u)[keep] ** 2)))
        print(f'| {name} | {x[-1] - x[0]:.0f} | ' + ' | '.join(f'{c * 1e3:.4f}' for c in cells)
              + ' |')


def _straight(self, gap_ns, after_ns, after, speed):
    """The old bridge: a straight line between the samples either side of the gap."""
    return np.interp(gap_ns, [self.stamps[-1], after_ns[0]], [self.accel[-1], after[0]])


def smoother_error(run, at: float, length: float, window_s: float = 12.0) -> float:
    """Largest D1 error (m) within 50 m of the dropout of the exact-physics baseline: the
    fixed-interval Kalman smoother on every sample within window_s of it
    (bench_gap_baseline.GapSmoother, the Bayes-optimal estimate in the model)."""
    t = run.t_true_s - run.t_true_s[0]
    gap = (t >= at) & (t < at + length)
    win = np.abs(t - at) <= window_s
    smoother = GapSmoother(VehicleParams().as_array(), float(np.median(run.speed_mps)),
                           run.accel_covariance, run.rate_hz, ~gap[win])
    u_s = smoother.smooth(vertical(run.accel[win], 'z') - InversionConfig().gravity_mps2)[0]
    chain, keep = run.chainage_m[win], ~gap[win]
    err = d1_errors(run.chainage_m, run.truth_u_m, chain[keep], smoothed_d1(chain, u_s)[keep],
                    float(np.interp(at, t, run.chainage_m)))
    return float(np.max(np.abs(err)))


def dropout_table() -> None:
    print('\n(e) dropouts (ADXL355 model, 20 m/s, 8 places in 2 runs), D1 error mm')
    header('dropout s', 'bridge', 'max within 50 m (mean)', 'max within 50 m (worst)',
           'max <= 0.3 mm', 'RMS 100 m after (mean)', 'gap term std, largest within 50 m')
    runs = [run_scenario('german-low', 20.0, 40.0, None, imu_spec('adxl355', dropout_fraction=0),
                         seed=s, defects='dip@400:len=6:depth=8e-3') for s in (1, 3)]
    default = InversionConfig()
    for length in (0.05, 0.2, 1.0):
        res: dict[str, list[tuple[float, ...]]] = {
            f'model, hold {default.gap_hold_s:g} s (default)': [], 'model, no hold': [],
            'straight line': [], 'reset': [], 'exact baseline: Kalman smoother, all samples': []}
        for run, at in itertools.product(runs, (10.0, 15.0, 20.0, 25.0)):
            t = run.t_true_s - run.t_true_s[0]
            keep = ~((t >= at) & (t < at + length))
            x_gap = float(np.interp(at, t, run.chainage_m))
            for name in res:
                if name.startswith('exact'):
                    res[name].append((smoother_error(run, at, length), np.nan, np.nan))
                    continue
                cfg = {'reset': InversionConfig(max_bridge_s=0.01),
                       'model, no hold': InversionConfig(gap_hold_s=0.0)}.get(name)
                with mock.patch.object(GapFiller, 'fill', _straight) if name == 'straight line' \
                        else mock.patch.object(GapFiller, 'fill', GapFiller.fill):
                    chain, out = reconstruct(run, cfg, keep)
                big = near(chain, out.u_m, run.chainage_m, run.truth_u_m, x_gap)[0]
                after = near(chain, out.u_m, run.chainage_m, run.truth_u_m, x_gap + 50.0)[1]
                std = np.max(out.gap_std_m[np.abs(chain - x_gap) <= 50.0])
                res[name].append((big, after, std))
        for name, values in res.items():
            big, after, std = np.array(values).T * 1e3
            term = f'{std.max():.3f}' if name.startswith('model') else ''
            rms = '' if name.startswith('exact') else f'{after.mean():.3f}'
            print(f'| {length:g} | {name} | {big.mean():.3f} | {big.max():.3f} | '
                  f'{np.mean(big <= 0.3):.2f} | {rms} | {term} |')


def gap_model_table(draws: int = 40) -> None:
    """(e2) 0.2 s dropouts on tracks drawn from the smoother's own model (where it is exactly
    Bayes-optimal): the smoother against the pipeline (bench_gap_baseline.model_monte_carlo)."""
    print(f'\n(e2) 0.2 s dropout on {draws} tracks drawn from the model (German low, ADXL355 '
          'noise, 20 m/s), largest D1 error within 50 m, mm')
    header('estimate', 'mean', 'worst', 'max <= 0.3 mm')
    for name, big in model_monte_carlo(draws, 0.2).items():
        print(f'| {name.split(": ")[1]} | {big.mean() * 1e3:.3f} | {big.max() * 1e3:.3f} | '
              f'{np.mean(big <= 3e-4):.2f} |')


def mismatch_table(length: float, seed: int) -> None:
    nominal = VehicleParams()
    true = VehicleParams(**{**nominal.__dict__, **{k: getattr(nominal, k) * f
                                                   for k, f in MISMATCH.items()}})
    run = run_scenario('german-low', 30.0, length / 30.0, None, 'bmi088', seed=seed,
                       defects=DEFECTS, vehicle=true)
    print('\n(f) parameter mismatch: true k_s +15 %, k_us -10 %, c -15 %; BMI088 model, 30 m/s')
    header('inversion with', 'D1 RMSE mm', 'dip peak error mm')
    for name, vehicle in (('nominal parameters', nominal), ('true parameters', true)):
        chain, out = reconstruct(run, vehicle=vehicle)
        s = score(chain, out.u_m, run.chainage_m, run.truth_u_m, defect=DIP)
        print(f'| {name} | {s.rmse * 1e3:.4f} | {s.peak_error * 1e3:.4f} |')
    b = baseline(run, 30.0, true.as_array())
    print(f'| exact baseline (FFT, true parameters) | {b.rmse * 1e3:.4f} | '
          f'{b.peak_error * 1e3:.4f} |')


def main() -> None:
    parser = run_options(__doc__, 800.0)
    parser.add_argument('--multirate', action='store_true',
                        help='add the multirate against single-rate table')
    parser.add_argument('--tables', default='abcdefgh',
                        help='tables to print (default abcdefgh)')
    args = parser.parse_args()
    if 'a' in args.tables:
        err = paper_mode()
        print(f'(a) paper mode, feedback K = 1000, no band, 10 m/s: relative error {err:.2e} '
              f'(target <= 1e-3: {"yes" if err <= 1e-3 else "no"})\n')
    tables = {'b': lambda: methods_table(args.length, args.seed, args.multirate),
              'c': lambda: delay_table(args.length, args.seed),
              'd': lambda: variable_speed_table(args.seed),
              'e': lambda: (dropout_table(), gap_model_table()),
              'f': lambda: mismatch_table(args.length, args.seed),
              'g': calibration_table, 'h': coverage_table}  # the uq engineer's benchmarks
    for key, table in tables.items():
        if key in args.tables:
            table()


if __name__ == '__main__':
    main()
