"""IMU checks on collected samples: rate, stamp jitter, monotonicity, gravity, noise density.

Inputs are arrays in arrival order: stamps_ns (N,) int64 header stamps and accel (N, 3)
specific force x, y, z in m/s^2 (REP 145: +g on z at rest, z up).

Noise density band: from a quarter to half of the sensor's anti-alias cut-off (-6 dB), e.g.
62.5-125 Hz for the adxl355 preset (cut-off 250 Hz at 1 kHz) and 40-80 Hz for bmi088 (160 Hz at
400 Hz). That is above the car body's rigid and flexural modes (below about 25 Hz), so at rest
the band holds sensor noise only, and inside the filter's passband (within 0.6 dB). On a
moving train wheel-rail vibration can still raise the band: the PSD is a Welch median over
segments and a median over the band's bins (robust to bursts and spectral lines), and when the
IMU shows motion (RMS above ``MOTION_RMS_MPS2`` in ``MOTION_BAND_HZ``) a noise density above the
preset is a WARN (repeat at rest), not a FAIL.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import signal

from railgsa_ros.health.items import FAIL, PASS, WARN, Item
from railgsa_ros.imu import UG, G, ImuSpec
from railgsa_ros.input.options import REORDER_WINDOW_S

RATE_TOLERANCE = 0.02  #: relative deviation of the rate from the expected one
LOST_WARN = 0.05  #: fraction of samples missing between first and last stamp
JITTER_LIMITS = (0.25, 0.5)  #: stamp jitter std / period: PASS up to, WARN up to
GRAVITY_TOLERANCE = 0.05  #: relative deviation of |mean specific force| from g
TILT_LIMITS_DEG = (5.0, 15.0)  #: angle between gravity and the +z axis: PASS up to, WARN up to
NOISE_RATIO = (0.5, 2.0)  #: measured / preset noise density accepted
NOISE_BAND = (0.25, 0.5)  #: noise band as fractions of the anti-alias -6 dB cut-off
MOTION_BAND_HZ = (0.5, 20.0)  #: car-body motion band
MOTION_RMS_MPS2 = 0.05  #: RMS in MOTION_BAND_HZ above which the car body moves, m/s^2
MIN_SEGMENT = 64  #: shortest Welch segment, samples
AXES = 'xyz'


def steps_ns(stamps_ns: np.ndarray) -> np.ndarray:
    """Stamp steps in arrival order, ns (float); negative where stamps go backwards."""
    return np.diff(np.asarray(stamps_ns, np.int64)).astype(float)


def _peak_period(rel_ns: np.ndarray, period: float, samples: int, width: float,
                 points: int) -> float:
    """The candidate period within +-``width`` (relative) of ``period`` at which the first
    ``samples`` stamps line up best: the largest |sum exp(2 pi i t / T)| (a periodogram of the
    stamps), ns."""
    candidates = period * (1.0 + np.linspace(-width, width, points))
    turns = np.exp(2j * np.pi * rel_ns[None, :samples] / candidates[:, None])
    return float(candidates[np.argmax(np.abs(turns.sum(axis=1)))])


def _block_period(rel_ns: np.ndarray, period: float, block: float) -> float:
    """Least-squares period (ns) over blocks of ``block`` periods, each with its own offset:
    within a block the sample numbers are the stamps' distances from the block's mean phase in
    whole periods, so a dropout or a jittered stamp never shifts the numbers of the others."""
    _, ids = np.unique(np.floor(rel_ns / (block * period)).astype(np.int64),
                       return_inverse=True)
    turn = np.exp(2j * np.pi * rel_ns / period)
    phase = np.angle(np.bincount(ids, turn.real) + 1j * np.bincount(ids, turn.imag))
    number = np.rint(rel_ns / period - phase[ids] / (2 * np.pi))
    count = np.bincount(ids)
    dx = number - (np.bincount(ids, number) / count)[ids]
    dy = rel_ns - (np.bincount(ids, rel_ns) / count)[ids]
    den = float(np.dot(dx, dx))
    return float(np.dot(dx, dy)) / den if den > 0 else math.nan


def measured_rate(stamps_ns: np.ndarray) -> float:
    """Sample rate of the stamps, Hz; NaN with fewer than 3 stamps.

    Robust to dropouts (even most samples lost in short bursts) and to stamp jitter up to a
    quarter period, to within 0.2 % (1e-5 at a tenth of a period): a first guess from the
    shorter steps, refined by the stamps' periodogram (within 30 %, then 0.2 %), then by
    least squares over blocks of 20, 200, ... periods until one block spans all stamps.
    """
    stamps = np.asarray(stamps_ns, np.int64)
    steps = np.diff(stamps).astype(float)
    steps = steps[steps > 0]
    if steps.size < 2:
        return math.nan
    period = float(np.median(steps[steps <= 2.0 * np.percentile(steps, 25)]))
    rel = (stamps - stamps[0]).astype(float)
    period = _peak_period(rel, period, 256, 0.3, 601)
    period = _peak_period(rel, period, 4096, 2e-3, 81)
    span, block = float(np.ptp(rel)), 20.0
    while period > 0:
        period = _block_period(rel, period, block)
        if block * period >= span:
            break
        block *= 10.0
    return 1e9 / period if period > 0 else math.nan


def rate_item(stamps_ns: np.ndarray, expected_hz: float, duration_s: float) -> Item:
    """Stamp rate within RATE_TOLERANCE of ``expected_hz``. WARN when more than LOST_WARN of
    the samples are missing between the first and the last stamp (dropouts), or when fewer
    messages arrived per second of listening than the stamps advance (not real time: the
    publisher falls behind or a link drops messages)."""
    expected = f'{expected_hz:g} Hz +- {RATE_TOLERANCE:.0%}'
    rate = measured_rate(stamps_ns)
    if not math.isfinite(rate):
        return Item('imu rate', FAIL, f'{len(stamps_ns)} messages', expected,
                    'no IMU stream: check the topic name, the driver and the cabling')
    span_s = float(np.ptp(np.asarray(stamps_ns, np.int64))) / 1e9
    lost = max(0.0, 1.0 - len(stamps_ns) / (span_s * rate + 1.0))
    received = len(stamps_ns) / duration_s
    value = f'{rate:.1f} Hz, {lost:.1%} lost, {received:.0f} msg/s received'
    if abs(rate / expected_hz - 1.0) > RATE_TOLERANCE:
        return Item('imu rate', FAIL, value, expected,
                    'the output data rate differs from the sensor preset: wrong preset or '
                    'driver setting (the nodes assume rate_hz)')
    if lost > LOST_WARN:
        return Item('imu rate', WARN, value, expected,
                    'samples missing: dropouts in the driver or a congested link')
    if received < (1.0 - LOST_WARN) * rate:
        return Item('imu rate', WARN, value, expected,
                    'fewer messages than the stamps advance: the publisher falls behind real '
                    'time or messages are dropped on the way')
    return Item('imu rate', PASS, value, expected)


def jitter_item(stamps_ns: np.ndarray, expected_hz: float) -> Item:
    """Stamp jitter (std) from the median absolute deviation of the steps: for white stamp
    noise of std s the steps have std s * sqrt(2); dropouts are outliers the MAD ignores."""
    period_ms = 1e3 / expected_hz
    expected = f'<= {JITTER_LIMITS[0] * period_ms:.3g} ms ({JITTER_LIMITS[0]:.0%} of a period)'
    steps = steps_ns(stamps_ns)
    if steps.size < 2:
        return Item('stamp jitter', FAIL, 'no stamps', expected)
    mad = float(np.median(np.abs(steps - np.median(steps))))
    jitter_ms = 1.4826 * mad / math.sqrt(2.0) / 1e6
    value = f'{jitter_ms:.3g} ms std'
    ratio = jitter_ms / period_ms
    if ratio <= JITTER_LIMITS[0]:
        return Item('stamp jitter', PASS, value, expected)
    hint = 'stamp in the driver at sampling time (sensor clock), not on reception'
    return Item('stamp jitter', WARN if ratio <= JITTER_LIMITS[1] else FAIL, value, expected,
                hint)


def monotonic_item(stamps_ns: np.ndarray) -> Item:
    """Stamps in arrival order: a stamp equal to the newest before it (duplicate), or below it
    by more than the nodes' default ``reorder_window_s``, FAILs (the nodes reject such samples);
    out of order within that window WARNs (the nodes re-order it, at the window's latency)."""
    stamps = np.asarray(stamps_ns, np.int64)
    if stamps.size == 0:
        return Item('stamp order', FAIL, 'no stamps', '0 out of order, 0 duplicates')
    newest = np.maximum.accumulate(stamps)[:-1]
    behind = newest - stamps[1:]
    ooo, dup = int(np.sum(behind > 0)), int(np.sum(behind == 0))
    value = f'{ooo} out of order, {dup} duplicates in {stamps.size}'
    if ooo:
        value += f' (by up to {behind.max() / 1e6:.4g} ms)'
    window_ms = REORDER_WINDOW_S * 1e3
    if dup or (ooo and behind.max() > REORDER_WINDOW_S * 1e9):
        return Item('stamp order', FAIL, value, '0 out of order, 0 duplicates',
                    'the driver publishes stamps that go backwards (beyond reorder_window_s, '
                    f'{window_ms:g} ms) or repeat: check its clock')
    if ooo:
        return Item('stamp order', WARN, value, '0 out of order, 0 duplicates', (
            f'the nodes re-order stamps within reorder_window_s ({window_ms:g} ms, its '
            'latency on every output); stamp in the driver at sampling time and publish in order'))
    return Item('stamp order', PASS, value, '0 out of order, 0 duplicates')


def gravity_item(accel: np.ndarray) -> Item:
    """Gravity on +z (REP 145): mean specific force along the axis with the largest |mean|,
    its tilt from +z and its magnitude against g."""
    expected = (f'+z, {G:.2f} m/s^2 +- {GRAVITY_TOLERANCE:.0%}, tilt <= {TILT_LIMITS_DEG[0]:g} '
                f'deg')
    acc = np.asarray(accel, float).reshape(-1, 3)
    acc = acc[np.isfinite(acc).all(axis=1)]
    if acc.shape[0] == 0:
        return Item('gravity axis', FAIL, 'no finite samples', expected)
    mean = acc.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    axis = int(np.argmax(np.abs(mean)))
    label = f'{"+" if mean[axis] > 0 else "-"}{AXES[axis]}'
    tilt = math.degrees(math.acos(np.clip(mean[2] / norm, -1.0, 1.0))) if norm > 0 else 180.0
    value = f'{label} {norm:.3f} m/s^2, tilt {tilt:.1f} deg'
    if label != '+z':
        hint = ('upside down: turn the sensor over (z up, REP 145)' if label == '-z' else
                f'gravity on {label}: the sensor is rotated; mount it with z up (REP 145)')
        return Item('gravity axis', FAIL, value, expected, hint)
    if abs(norm / G - 1.0) > GRAVITY_TOLERANCE:
        return Item('gravity axis', FAIL, value, expected,
                    'magnitude is not g: units (g instead of m/s^2?) or scale factor')
    if tilt > TILT_LIMITS_DEG[0]:
        return Item('gravity axis', WARN if tilt <= TILT_LIMITS_DEG[1] else FAIL, value,
                    expected, 'the sensor is tilted: level the mounting')
    return Item('gravity axis', PASS, value, expected)


def noise_psd(accel: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(f Hz, PSD (F, 3) (m/s^2)^2/Hz): Welch median over segments of about one second
    (power of two), linear detrend; fewer samples shorten the segments."""
    n = accel.shape[0]
    nperseg = 2 ** int(math.log2(max(min(rate_hz, n / 4), 1.0)))
    return signal.welch(accel, rate_hz, nperseg=nperseg, average='median', detrend='linear',
                        axis=0)


def noise_item(stamps_ns: np.ndarray, accel: np.ndarray, spec: ImuSpec) -> Item:
    """Noise density per axis in the NOISE_BAND against ``spec.noise_density`` (see the module
    docstring for the band and the moving-train rule)."""
    name = 'noise density'
    density = spec.noise_density / UG
    low, high = (r * spec.antialias_hz for r in NOISE_BAND)
    expected = (f'{density:.3g} ug/sqrt(Hz) x{NOISE_RATIO[0]:g}-{NOISE_RATIO[1]:g} '
                f'({spec.name})')
    stamps = np.asarray(stamps_ns, np.int64)
    acc = np.asarray(accel, float).reshape(-1, 3)
    keep = np.isfinite(acc).all(axis=1)
    order = np.argsort(stamps[keep], kind='stable')
    acc = acc[keep][order]
    rate = measured_rate(stamps[keep][order])
    if not math.isfinite(rate) or acc.shape[0] < 4 * MIN_SEGMENT:
        return Item(name, FAIL, f'{acc.shape[0]} samples', expected,
                    'too few samples for a spectrum: run longer (--duration)')
    f, psd = noise_psd(acc, rate)
    in_band = (f >= low) & (f <= min(high, 0.45 * rate))
    if not in_band.any():
        return Item(name, FAIL, f'no frequencies in {low:g}-{high:g} Hz at {rate:.0f} Hz',
                    expected, 'the rate does not fit the preset')
    measured = np.sqrt(np.median(psd[in_band], axis=0)) / UG
    df = f[1] - f[0]
    motion = (f >= MOTION_BAND_HZ[0]) & (f <= MOTION_BAND_HZ[1])
    moving = bool(np.any(np.sqrt(psd[motion].sum(axis=0) * df) > MOTION_RMS_MPS2))
    value = (', '.join(f'{a} {m:.3g}' for a, m in zip(AXES, measured, strict=True))
             + f' ug/sqrt(Hz) in {low:.3g}-{high:.3g} Hz' + (', moving' if moving else ''))
    if density == 0:
        return Item(name, PASS, value, f'any ({spec.name} has no noise)')
    ratio = measured / density
    if np.all((ratio >= NOISE_RATIO[0]) & (ratio <= NOISE_RATIO[1])):
        return Item(name, PASS, value, expected)
    if np.any(ratio < NOISE_RATIO[0]):
        return Item(name, FAIL, value, expected,
                    f'quieter than {spec.name}: another sensor than the configured preset?')
    if moving:
        return Item(name, WARN, value, expected,
                    'the train moves: vibration masks the sensor noise; repeat at rest')
    return Item(name, FAIL, value, expected,
                f'noisier than {spec.name} at rest: loose mounting, a nearby vibration '
                'source, a faulty sensor or another sensor than the preset')
