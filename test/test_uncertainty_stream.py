"""UncertaintyStream: bands against brute-force Monte Carlo through the same inverse, window
indices against uq.analyze on the same quantity, stamps against the nominal pipeline, chunking."""

from __future__ import annotations

from dataclasses import fields
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest

from railgsa_ros.errors import ConfigError
from railgsa_ros.input.options import InputOptions
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.inverse.quality import Quality
from railgsa_ros.scenario import run_scenario
from railgsa_ros.uncertainty import Band, UncertaintyConfig, UncertaintyStream, offline_bands
from railgsa_ros.uncertainty.config import load_config
from railgsa_ros.uncertainty.parameters import table3
from railgsa_ros.uncertainty.stream import band_statistics, order_statistics
from railgsa_ros.uncertainty.surrogate import build_design
from railgsa_ros.uncertainty.windows import WindowAnalyzer
from railgsa_ros.uq import analyze
from railgsa_ros.uq.germ import sobol
from railgsa_ros.uq.pce import PCE
from railgsa_ros.vehicle import PARAM_NAMES, VehicleParams

REPO = Path(__file__).resolve().parents[1]
RATE = 500.0
# Paper mode (feedback inversion, no band: D = 0) keeps brute force cheap: 8 s at 10 m/s puts
# the paper profile's largest deviation (70 m) at t = 7 s, the paper's quantity of interest.
PAPER = InversionConfig(method='feedback', band='none', rate_hz=RATE, gap_policy='reset')
# the ideal sensor repeats values on the flat start of the paper profile: no stuck check
IDEAL = InputOptions(stuck_s=0.0)
WARM = round(PAPER.taper_s * RATE)  # the fade-in after the start: INVALID outputs
DISTS = table3()
COLUMNS = [PARAM_NAMES.index(n) for n in DISTS]


@pytest.fixture(scope='module')
def run():
    return run_scenario('paper', 10.0, 8.0, RATE, 'ideal', 0)


def _thetas(physical: np.ndarray) -> np.ndarray:
    """Vehicles (N, 5): Table 1 with the uncertain columns set to ``physical`` (N, 3)."""
    theta = np.tile(VehicleParams().as_array(), (len(physical), 1))
    theta[:, COLUMNS] = physical
    return theta


def _bank(run, theta: np.ndarray) -> np.ndarray:
    """Nominal-pipeline outputs (N, K) for vehicles theta over the whole run."""
    pipe = InversionPipeline(PAPER, theta)
    first = pipe.push(run.stamps_ns, run.accel[:, 2], run.speed_mps)
    return np.concatenate([first.u_m, pipe.flush().u_m], axis=1)


def _push_chunks(stream: UncertaintyStream, run, sizes: np.ndarray) -> list:
    edges = np.concatenate([[0], np.cumsum(sizes)])
    updates = [stream.push(run.stamps_ns[lo:hi], run.accel[lo:hi, 2], run.speed_mps[lo:hi])
               for lo, hi in pairwise(edges) if hi > lo]
    return [*updates, stream.flush()]


@pytest.fixture(scope='module')
def brute(run):
    """Monte Carlo through the same inverse: 1000 vehicles drawn from Table 3, (1000, K)."""
    xi = np.random.default_rng(7).standard_normal((1000, len(DISTS)))
    return _bank(run, _thetas(np.stack([d.from_xi(xi[:, i]) for i, d in
                                        enumerate(DISTS.values())], axis=1)))


@pytest.mark.parametrize(('rule', 'size', 'tol'), [('pem5', 0, 0.035), ('lstsq', 40, 0.04)])
def test_band_matches_brute_force_monte_carlo(run, brute, rule, size, tol):
    config = UncertaintyConfig(inversion=PAPER, rule=rule, rule_size=size)
    band = offline_bands(run.stamps_ns, run.accel, (run.stamps_ns, run.speed_mps), config=config,
                         options=IDEAL)
    assert brute.shape[1] == len(band)
    # the fade-in after the start is INVALID (NaN band), the rest VALID
    assert np.all(band.quality[:WARM] == Quality.INVALID) and np.all(band.quality[WARM:] == 0)
    assert np.all(np.isnan(band.mean_m[:WARM]))
    band = Band(*(getattr(band, f.name)[WARM:] for f in fields(Band)))
    brute = brute[:, WARM:]
    scale = np.abs(run.truth_u_m).max()
    mean, se = brute.mean(axis=0), brute.std(axis=0) / np.sqrt(brute.shape[0])
    lower, upper = np.quantile(brute, [0.025, 0.975], axis=0)
    # The band is wide (at the peak 16 % of the 4 mm deviation) and not a constant offset.
    assert np.ptp(upper - lower) > 0.05 * scale
    # Mean vs Monte Carlo mean: within the sampling error (pem5: 0.1 % of the scale).
    assert np.all(np.abs(band.mean_m - mean) <= 4 * se + 2e-3 * scale)
    # Quantiles (measured, % of the scale): pem5 1.0-1.1 against 2000 brute-force samples, 2.0-2.3
    # against these 1000 (whose own quantile error at the peak is ~1 % per sigma); gauss (27
    # points) gives the same as pem5, so this is order-2 truncation plus Monte Carlo noise; the
    # germ sample size (1024 vs 16384) moves it by 0.1 %.
    assert np.max(np.abs(band.lower_m - lower)) < tol * scale
    assert np.max(np.abs(band.upper_m - upper)) < tol * scale
    assert np.all(band.lower_m <= band.mean_m) and np.all(band.mean_m <= band.upper_m)


def test_window_indices_equal_uq_analyze_on_the_same_quantity(run):
    config = UncertaintyConfig(inversion=PAPER, window_length=100.0, n_mc=20000)
    updates = _push_chunks(UncertaintyStream(config, options=IDEAL), run, np.full(40, 100))
    records = [w for up in updates for w in up.windows]
    assert [r.qoi for r in records] == ['peak', 'rms']
    peak = records[0]
    stamps = run.stamps_ns
    k = int(np.flatnonzero(stamps == peak.peak_stamp_ns)[0])
    assert abs(k / RATE - 7.0) < 0.1  # the paper's t = 7 s, found on the stream
    # the window holds the samples that are not INVALID (after the fade-in)
    assert (peak.first_stamp_ns, peak.last_stamp_ns, peak.samples) == (
        stamps[WARM], stamps[-1], stamps.size - WARM)

    def model(physical: np.ndarray) -> np.ndarray:
        u = _bank(run, _thetas(physical))
        return np.stack([u[:, k], np.sqrt(np.mean(u[:, WARM:] ** 2, axis=1))], axis=1)

    ref = analyze(model, list(DISTS.values()), order=2, rule='pem5', delta=True,
                  delta_samples=config.n_mc, seed=config.seed)
    assert ref.n_evaluations == peak.evaluations == 19
    for i, rec in enumerate(records):
        np.testing.assert_allclose(rec.sobol_first, ref.sobol_first[i], atol=1e-9)
        np.testing.assert_allclose(rec.sobol_total, ref.sobol_total[i], atol=1e-9)
        np.testing.assert_allclose(rec.delta, ref.delta[i], atol=2e-3)
        np.testing.assert_allclose([rec.mean_m, rec.std_m], [ref.mean[i], ref.std[i]],
                                   rtol=1e-9)
    # k_s and c drive the peak; the contact stiffness k_us barely matters (paper Fig. 13).
    assert peak.sobol_total[1] < 0.05 < min(peak.sobol_total[0], peak.sobol_total[2])


def _dirty(run, rng):
    """The run with NaNs, a duplicate, an out-of-order stamp and a 0.1 s gap."""
    stamps, acc = run.stamps_ns[:1500].copy(), run.accel[:1500, 2].copy()
    acc[[100, 700]] = np.nan
    stamps[300] = stamps[299]
    stamps[[500, 501]] = stamps[[501, 500]]
    keep = np.ones(stamps.size, bool)
    keep[900:950] = False
    return stamps[keep], acc[keep], run.speed_mps[:1500][keep], rng.integers(1, 200, 60)


def test_band_stamps_are_the_nominal_pipeline_stamps_one_to_one(run):
    rng = np.random.default_rng(3)
    stamps, acc, speed, sizes = _dirty(run, rng)
    inversion = InversionConfig(rate_hz=RATE)  # the default spectral D1 method
    stream = UncertaintyStream(UncertaintyConfig(inversion=inversion, qoi=''), options=IDEAL)
    nominal = InversionPipeline(inversion, VehicleParams())
    edges = np.concatenate([[0], np.cumsum(sizes)])
    got, want = [], []
    for lo, hi in pairwise(edges):
        got.append(stream.push(stamps[lo:hi], acc[lo:hi], speed[lo:hi]).band.stamps_ns)
        want.append(nominal.push(stamps[lo:hi], acc[lo:hi], speed[lo:hi]).stamps_ns)
    got.append(stream.flush().band.stamps_ns)
    want.append(nominal.flush().stamps_ns)
    np.testing.assert_array_equal(np.concatenate(got), np.concatenate(want))
    counts = stream.counters
    assert (counts['nan'], counts['duplicate'], counts['out_of_order']) == (2, 1, 1)
    assert counts['gap'] == 1
    assert {k: counts[k] for k in ('nan', 'duplicate', 'out_of_order', 'gap', 'emitted')} == \
        {k: nominal.counters[k] for k in ('nan', 'duplicate', 'out_of_order', 'gap', 'emitted')}


def test_outputs_do_not_depend_on_chunking(run):
    config = UncertaintyConfig(inversion=PAPER, window_length=2.0, n_mc=4096)
    rng = np.random.default_rng(5)
    one = _push_chunks(UncertaintyStream(config, options=IDEAL), run, [run.stamps_ns.size])
    many = _push_chunks(UncertaintyStream(config, options=IDEAL), run, rng.integers(1, 300, 40))
    tiny = _push_chunks(UncertaintyStream(config, options=IDEAL), run, np.ones(500, int))
    ref = one[0].band.__class__.concat([u.band for u in one])
    scale = np.nanmax(np.abs(ref.mean_m))
    for updates in (many, tiny):
        band = ref.__class__.concat([u.band for u in updates])
        np.testing.assert_array_equal(band.stamps_ns[:len(band)], ref.stamps_ns[:len(band)])
        # The nominal feedback pipeline itself (marginally damped slow poles, no band) moves by
        # 2.2e-10 of the scale between chunkings of this run: the bands inherit no more.
        for name in ('lower_m', 'mean_m', 'upper_m'):
            np.testing.assert_allclose(getattr(band, name), getattr(ref, name)[:len(band)],
                                       rtol=0, atol=1e-9 * scale)
    windows = [[w for u in ups for w in u.windows] for ups in (one, many)]
    assert len(windows[0]) == len(windows[1]) == 8  # 4 windows of 2 s, 2 QoIs each
    for a, b in zip(*windows, strict=True):
        assert (a.qoi, a.first_stamp_ns, a.last_stamp_ns, a.peak_stamp_ns, a.samples) == \
            (b.qoi, b.first_stamp_ns, b.last_stamp_ns, b.peak_stamp_ns, b.samples)
        np.testing.assert_allclose(a.sobol_total, b.sobol_total, atol=1e-9)
        np.testing.assert_allclose(a.delta, b.delta, atol=1e-3)


def test_windows_in_metres_follow_chainage(run):
    config = UncertaintyConfig(inversion=PAPER, window_length=25.0, window_unit='m',
                               qoi='rms', n_mc=2048)
    records = [w for u in _push_chunks(UncertaintyStream(config, options=IDEAL), run,
                                       [1000, 1000, 2000]) for w in u.windows]
    assert len(records) == 4  # 80 m of track
    for i, rec in enumerate(records):
        assert i * 25.0 <= rec.chainage_start_m <= rec.chainage_end_m < (i + 1) * 25.0
    assert sum(r.samples for r in records) == run.stamps_ns.size - WARM  # not the INVALID ones


def test_band_quantiles_are_those_of_the_sampled_surrogate(run):
    """band_statistics (sort + rank interpolation in coefficient space) against np.quantile over
    the PCE evaluated at the germ sample, sample by sample, including the order-2 terms."""
    config = UncertaintyConfig(inversion=PAPER, germ_samples=1000, lower_quantile=0.1,
                               upper_quantile=0.8)
    design = build_design(config, VehicleParams(), DISTS)
    u = _bank(run, design.theta)[:, ::7]  # (P, K): K = 572 is not a multiple of GEMM_ROWS
    lower, mean, upper = band_statistics(design, (0.1, 0.8), u)
    pce = PCE(design.alpha, design.projector @ u, design.germ)
    samples = pce(sobol(len(DISTS), 1000, config.seed, design.germ))  # (S, K)
    scale = np.abs(mean).max()
    np.testing.assert_allclose(mean, pce.mean, rtol=0, atol=1e-14 * scale)
    for got, q in ((lower, 0.1), (upper, 0.8)):
        np.testing.assert_allclose(got, np.quantile(samples, q, axis=0), rtol=0,
                                   atol=1e-14 * scale)


def test_band_quantiles_of_the_default_design_are_those_of_np_quantile(run):
    """The default 1024 germ samples and 2.5/97.5 % quantiles take the piecewise selection of
    order_statistics: the band is np.quantile's over the same surrogate samples, bit for bit up
    to the last rounding of the products (same floats selected, same interpolation)."""
    config = UncertaintyConfig(inversion=PAPER)
    design = build_design(config, VehicleParams(), DISTS)
    u = _bank(run, design.theta)[:, ::3]
    lower, mean, upper = band_statistics(design, (0.025, 0.975), u)
    coef = design.projector @ u
    samples = coef[1:].T @ design.germ_basis  # (K, S) deviations, as band_statistics forms them
    for got, q in ((lower, 0.025), (upper, 0.975)):
        np.testing.assert_allclose(got, mean + np.quantile(samples, q, axis=1), rtol=1e-12,
                                   atol=1e-15 * np.abs(mean).max())


@pytest.mark.parametrize('size', [1024, 1000, 1001, 512, 256, 40])
@pytest.mark.parametrize('ranks', [[25, 26, 997, 998], [0, 1, 30, 2], [-1, -2, 5],
                                   [100, 101, 900, 901], [500, 511]])
def test_order_statistics_are_those_of_a_full_sort(size, ranks):
    """Bit for bit against np.sort: tails (piecewise selection), central ranks (full sort),
    sizes that do or do not split into pieces, ties, NaN and infinities."""
    rng = np.random.default_rng(size)
    values = rng.standard_normal((37, size))
    values[1] = np.round(values[1])  # ties
    values[2, ::17] = np.nan
    values[3, ::5] = np.inf
    values[4, ::3] = -np.inf
    values[5] = np.sort(values[5])[::-1]  # reversed
    ranks = np.array([r % size for r in ranks])
    expected = np.sort(values, axis=1)[:, ranks]
    np.testing.assert_array_equal(order_statistics(values, ranks), expected)


def test_deferred_windows_give_the_streamed_records(run):
    config = UncertaintyConfig(inversion=PAPER, window_length=0.5, n_mc=2048)
    design = build_design(config, VehicleParams(), DISTS)
    u = _bank(run, design.theta)
    mean = design.projector[0] @ u
    live, offline = WindowAnalyzer(config, design), WindowAnalyzer(config, design, defer=True)
    streamed = []
    for lo in range(0, run.stamps_ns.size, 300):
        sl = slice(lo, lo + 300)
        args = (run.stamps_ns[sl], run.chainage_m[sl], mean[sl], u[:, sl])
        streamed += live.push(*args)
        assert offline.push(*args) == []
    streamed += live.close()
    offline.close()
    deferred = offline.analyze_deferred()
    assert len(deferred) == len(streamed) == 2 * 16  # more than DEFER_BATCH windows
    # to rounding, but the compute time: BLAS may take another kernel (summation order) for a
    # batch, and a delta's kernel-density sign decisions can flip on 1 ulp (5e-5 seen, against
    # the estimator's own RMS error of 0.002-0.009)
    for a, b in zip(streamed, deferred, strict=True):
        for f in fields(a):
            want, got = getattr(a, f.name), getattr(b, f.name)
            if f.name == 'delta':
                np.testing.assert_allclose(got, want, rtol=0, atol=1e-3)
            elif isinstance(want, (float, np.ndarray)) and f.name != 'compute_s':
                np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
            elif f.name != 'compute_s':
                assert got == want, f.name


@pytest.mark.parametrize(('changes', 'field'), [
    ({'rule': 'pem5', 'order': 3}, 'order'), ({'qoi': 'peak,max'}, 'qoi'),
    ({'lower_quantile': 0.5, 'upper_quantile': 0.5}, 'lower_quantile'),
    ({'germ_samples': 4}, 'germ_samples'), ({'window_unit': 'km'}, 'window_unit')])
def test_bad_configuration_names_the_field(changes, field):
    with pytest.raises(ConfigError, match=field):
        UncertaintyStream(UncertaintyConfig.from_mapping(changes))


def test_unknown_parameter_and_uncertain_name_are_refused():
    with pytest.raises(ConfigError, match='bogus'):
        UncertaintyConfig.from_mapping({'bogus': 1})
    with pytest.raises(ConfigError, match='uncertain parameters'):
        UncertaintyStream(dists={'speed': DISTS['k_s']})


def test_params_file_holds_the_code_defaults():
    config = load_config(REPO / 'config' / 'uncertainty_node.yaml')
    assert config == UncertaintyConfig()
