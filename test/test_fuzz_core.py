"""Property-based fuzzing of the streaming core (no ROS): InputSanitizer, InversionPipeline
(spectral, feedback, kalman) and UncertaintyStream, each one long-lived object fed every
example in turn, as a node feeds it for months.

Chunks of 0..2500 samples continue the stream or jump (a gap, a huge step forward, backwards
a little or far, anywhere in the header-stamp range 1 ns .. 2^31 s) and carry injected faults:
accelerations NaN, +-inf, subnormal, 1e308 or any float, duplicated and backward stamps, stuck
stretches, wrong frame ids; speeds up to +-1 km/s (odometry), +-200 m/s for the Kalman
method (absurd ones: the regression tests at the end). Nothing raises, every emitted value
is finite, and every sample is counted exactly once: accepted or rejected by one reason.
"""

from __future__ import annotations

from typing import Any

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from railgsa_ros.input.sanitize import REASONS, InputSanitizer
from railgsa_ros.inverse.config import InversionConfig
from railgsa_ros.inverse.pipeline import InversionPipeline
from railgsa_ros.uncertainty import UncertaintyConfig, UncertaintyStream
from railgsa_ros.uncertainty.parameters import table3
from railgsa_ros.vehicle import VehicleParams

FUZZ = settings(max_examples=60, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
NS = 1_000_000_000
PERIOD_NS = 1_000_000  # 1 kHz
MAX_NS = (2**31 - 1) * NS + NS - 1  # newest header stamp (int32 sec, nanosec < 1e9)
G = 9.80665
STUCK_S = 0.3  #: stuck-sensor check, s (the 'stuck' fault holds a value for 0.6 s)
#: where a chunk starts relative to the previous one's last stamp, ns (None: anywhere)
STARTS = {'next': PERIOD_NS, 'gap': 50 * PERIOD_NS, 'far_forward': 10**15,
          'back': -20 * PERIOD_NS, 'far_back': -10**12, 'anywhere': None}
FAULT_VALUES = st.one_of(st.floats(), st.sampled_from(
    [np.nan, np.inf, -np.inf, 5e-324, 1e308, -1e308, 3 * G, 0.0]))
FAULTS = st.lists(st.tuples(st.floats(0, 1, exclude_max=True),
                            st.sampled_from(['value', 'duplicate', 'backward', 'stuck',
                                             'frame']), FAULT_VALUES), max_size=8)
#: speeds as odometry may send them (any finite value up to 1 km/s)
SPEEDS = st.one_of(st.floats(-1e3, 1e3), st.floats(-50, 80), st.just(40.0))
BANK_SPEEDS = st.one_of(st.floats(-200, 200), st.just(40.0))


class Stream:
    """The running clock of one fuzzed object; builds the next chunk."""

    def __init__(self) -> None:
        self.last_ns = NS
        self.pushed = 0

    def chunk(self, n: int, seed: int, start: str, anywhere_ns: int,
              faults: list[tuple[float, str, float]]) -> tuple[np.ndarray, ...]:
        """(stamps_ns, accel_up, frame_ids) of n samples after ``start``, faults injected."""
        rng = np.random.default_rng(seed)
        step = STARTS[start]
        first = anywhere_ns if step is None else self.last_ns + step
        stamps = first + np.arange(n, dtype=np.int64) * PERIOD_NS \
            + rng.integers(-100_000, 100_000, n)
        accel = G + 0.3 * rng.standard_normal(n)
        frames = np.full(n, 'imu_link', dtype=object)
        if n and seed % 2:  # half the chunks: a NaN at a random place
            accel[rng.integers(n)] = np.nan
        for where, kind, value in faults:
            if n == 0:
                break
            i = int(where * n)
            if kind == 'value':
                accel[i] = value
            elif kind == 'duplicate':
                stamps[i] = stamps[i - 1]
            elif kind == 'backward':
                stamps[i] -= int(abs(value) * NS) if np.isfinite(value) and abs(value) < 1e6 \
                    else 5 * NS
            elif kind == 'stuck':
                accel[i:i + 600] = accel[i]
            else:
                frames[i] = 'base_link'
        stamps = np.clip(stamps, 1, MAX_NS)
        if n:
            self.last_ns = int(stamps[-1])
        self.pushed += n
        return stamps, accel, frames


chunks = st.tuples(st.one_of(st.integers(0, 40), st.integers(500, 2500)),
                   st.integers(0, 2**32 - 1), st.sampled_from(sorted(STARTS)),
                   st.integers(1, MAX_NS), FAULTS)


def config(method: str = 'spectral') -> InversionConfig:
    """Defaults with a short band delay (designed at 40 m/s)."""
    return InversionConfig(method=method, min_design_speed_mps=40.0, speed_mps=40.0)


def accounted(counters: dict[str, int], pushed: int) -> bool:
    """Every pushed sample accepted or rejected by exactly one reason."""
    return counters.get('accepted', 0) + sum(counters.get(r, 0) for r in REASONS) == pushed


@pytest.fixture(scope='module')
def sanitizer() -> tuple[InputSanitizer, Stream]:
    """The node's sanitiser settings (bridge gaps, +-2 g range, imu_link), stuck check on."""
    cfg = config()
    return InputSanitizer(cfg.rate_hz, cfg.gap_factor, cfg.gap_policy, cfg.max_bridge_s,
                          cfg.saturation_mps2, cfg.saturation_margin_mps2, cfg.frame_id,
                          stuck_s=STUCK_S), Stream()


@FUZZ
@given(chunks, SPEEDS)
def test_sanitizer_output_is_clean_and_every_sample_counted(sanitizer: Any, spec: tuple,
                                                            speed: float) -> None:
    san, stream = sanitizer
    stamps, accel, frames = stream.chunk(*spec)
    clean = san.process(stamps, accel, speed, frames)
    assert accounted(san.counters, stream.pushed)
    assert np.all(np.isfinite(clean.accel)) and np.all(np.abs(clean.accel) < san.limit)
    assert np.all(np.isfinite(clean.speed))
    steps = np.diff(clean.stamps_ns)
    assert np.all((steps > 0) | clean.reset_before[1:])  # increasing within each stream
    assert set(clean.stamps_ns[~clean.synthetic].tolist()) <= set(stamps.tolist())


@pytest.fixture(scope='module')
def pipelines() -> dict[str, tuple[InversionPipeline, Stream]]:
    return {m: (InversionPipeline(config(m), stuck_s=STUCK_S), Stream())
            for m in ('spectral', 'feedback', 'kalman')}


#: every fault and start once per method, before the generated examples: the coverage check
#: below then does not depend on what the generator happens to draw
EVERY_FAULT = [(0.1, 'stuck', 0.0), (0.5, 'value', 3 * G), (0.6, 'duplicate', 0.0),
               (0.7, 'backward', 0.5), (0.8, 'frame', 0.0)]
COVERING = [(m, (n, seed, start, 1, faults), 40.0, 40.0)
            for m in ('spectral', 'feedback', 'kalman')
            for n, seed, start, faults in ((2500, 1, 'next', EVERY_FAULT), (600, 2, 'gap', []),
                                           (600, 4, 'far_back', []))]


def covering(test: Any) -> Any:
    """``test`` with the COVERING examples."""
    for args in COVERING:
        test = example(*args)(test)
    return test


@covering
@settings(FUZZ, max_examples=150)
@given(st.sampled_from(['spectral', 'feedback', 'kalman']), chunks, SPEEDS, BANK_SPEEDS)
def test_pipeline_emits_only_finite_values(pipelines: dict, method: str, spec: tuple,
                                           speed: float, kalman_speed: float) -> None:
    pipe, stream = pipelines[method]
    stamps, accel, frames = stream.chunk(*spec)
    out = pipe.push(stamps, accel, kalman_speed if method == 'kalman' else speed, frames)
    assert len(out.chainage_m) == len(out.u_m) == len(out)
    assert np.all(np.isfinite(out.u_m)) and np.all(np.isfinite(out.chainage_m))
    assert accounted(pipe.counters, stream.pushed)


def test_pipelines_emitted_output(pipelines: dict) -> None:
    """The fuzz above reached the output path of every method (runs after it)."""
    for pipe, _ in pipelines.values():
        counts = pipe.counters
        assert counts.get('emitted', 0) > 2000, counts
        assert [r for r in (*REASONS, 'gap', 'time_reset') if not counts.get(r)] == [], counts


@pytest.fixture(scope='module')
def bank() -> tuple[UncertaintyStream, Stream]:
    cfg = UncertaintyConfig(rule='pem3', order=1, window_length=0.5, n_mc=256,
                            germ_samples=64, inversion=config())
    vehicle = VehicleParams()
    return UncertaintyStream(cfg, vehicle, table3(vehicle)), Stream()


@settings(FUZZ, max_examples=30)
@given(chunks, BANK_SPEEDS)
def test_uncertainty_stream_emits_only_finite_bands_and_windows(bank: Any, spec: tuple,
                                                                speed: float) -> None:
    stream_obj, stream = bank
    stamps, accel, frames = stream.chunk(*spec)
    update = stream_obj.push(stamps, accel, speed, frames)
    band = update.band
    ok = band.quality != 2  # INVALID samples (warm-up, tails of the resets) have a NaN band
    assert np.all(np.isfinite(band.chainage_m))
    for values in (band.lower_m, band.mean_m, band.upper_m):
        assert np.all(np.isfinite(values[ok])) and np.all(np.isnan(values[~ok]))
    assert np.all(band.lower_m[ok] <= band.upper_m[ok])
    for record in update.windows:
        for values in (record.sobol_first, record.sobol_total, record.delta,
                       [record.mean_m, record.std_m, record.chainage_start_m,
                        record.chainage_end_m]):
            assert np.all(np.isfinite(values)), record
    assert accounted(stream_obj.counters, stream.pushed)


def test_bank_emitted_output(bank: Any) -> None:
    """The bank fuzz above reached the band output (runs after it)."""
    assert bank[0].counters.get('emitted', 0) > 1000, bank[0].counters


# ------------------------------------------------------------- regressions found by fuzzing
def test_interleaved_clocks_in_one_batch() -> None:
    k = np.arange(2000)
    stamps = 10**12 + (k // 2) * PERIOD_NS + (k % 2) * 10 * NS
    san = InputSanitizer(1000.0)
    clean = san.process(stamps, np.full(k.size, G), 20.0)
    assert san.counters['time_reset'] > 0 and clean.stamps_ns.size > 0


@pytest.mark.parametrize('speed', [1e5, 1e12])
def test_kalman_with_absurd_odometry_speed(speed: float) -> None:
    pipe = InversionPipeline(InversionConfig(method='kalman'))
    out = pipe.push(np.array([NS, NS + PERIOD_NS]), np.array([G, G]), speed)
    assert np.all(np.isfinite(out.u_m))


def test_absurd_odometry_speed_keeps_the_chainage_finite() -> None:
    pipe = InversionPipeline(config())
    stamps = NS + np.arange(3000) * PERIOD_NS
    outs = [pipe.push(stamps + k * 3 * NS, np.full(3000, G), v)
            for k, v in enumerate((40.0, 1e308, 40.0))]
    assert all(np.all(np.isfinite(o.chainage_m)) for o in outs)
