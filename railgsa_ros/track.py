"""Vertical track irregularity: spectra, random synthesis, isolated defects and profile files.

Units: distance x in m, irregularity u in m (+z up, a dip is negative), spatial angular frequency
Omega in rad/m, one-sided spectra in m^2/(rad/m), so that var(u) = integral of S dOmega.

Random profiles use the spectral representation method (Shinozuka & Deodatis 1991):
u(x) = sum_k sqrt(2 S(Omega_k) dOmega) cos(Omega_k x + phi_k), phi_k uniform on [0, 2 pi), summed
by one inverse real FFT. The result is periodic with period P = N dx >= the requested length, so a
profile never repeats itself; ``dOmega = 2 pi / P``.
"""

from __future__ import annotations

from collections.abc import Callable
import csv
from dataclasses import dataclass
from functools import partial
from pathlib import Path
import re

import numpy as np
from scipy import fft

from railgsa_ros.errors import ConfigError

# German / ORE B176 vertical profile spectrum [rail_domain.md section 2, several codes agree]:
# S = A_v Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)). Omega_s = 0.438 belongs to
# the cross-level/gauge spectra and is not used here (a bug seen in public code).
GERMAN_OMEGA_C = 0.8246  # rad/m
GERMAN_OMEGA_R = 0.0206  # rad/m
GERMAN_AV = {'low': 4.032e-7, 'high': 1.080e-6}  # m*rad; low disturbance < high disturbance
# FRA spectrum [rail_domain.md section 2]: S = k A_v Omega_c^2 / (Omega^2 (Omega^2 + Omega_c^2)) in
# cm^2/(rad/m); A_v in cm^2*rad/m for classes 1..6, converted with 1e-4 m^2/cm^2.
FRA_K = 0.25
FRA_OMEGA_C = 0.8245  # rad/m
FRA_AV_CM2 = (1.2107, 1.0181, 0.6816, 0.5376, 0.2095, 0.0339)
CM2_TO_M2 = 1e-4

# EN 13848 wavelength bands of longitudinal level, m.
BANDS = {'D1': (3.0, 25.0), 'D2': (25.0, 70.0), 'D3': (70.0, 150.0)}
# Default synthesis band, m: covers D1-D3 with margin; the long-wave limit is the high-pass
# that the FRA spectrum needs (its variance diverges as Omega -> 0).
DEFAULT_WAVELENGTHS = (1.0, 200.0)

Psd = Callable[[np.ndarray], np.ndarray]


def german_psd(omega: np.ndarray, level: str = 'low') -> np.ndarray:
    """German (ORE B176) vertical profile spectrum, one-sided, m^2/(rad/m); omega in rad/m."""
    if level not in GERMAN_AV:
        raise ConfigError(f'german level: expected low or high, got {level!r}')
    omega = np.asarray(omega, dtype=float)
    oc2 = GERMAN_OMEGA_C ** 2
    return GERMAN_AV[level] * oc2 / ((omega ** 2 + GERMAN_OMEGA_R ** 2) * (omega ** 2 + oc2))


def fra_psd(omega: np.ndarray, cls: int = 6) -> np.ndarray:
    """FRA vertical profile spectrum of track class 1..6, one-sided, m^2/(rad/m).

    Diverges as omega^-2 at 0 (infinite variance): synthesise with a finite longest wavelength.
    """
    if cls not in range(1, 7):
        raise ConfigError(f'fra class: expected 1..6, got {cls!r}')
    omega = np.asarray(omega, dtype=float)
    oc2 = FRA_OMEGA_C ** 2
    with np.errstate(divide='ignore'):
        return CM2_TO_M2 * FRA_K * FRA_AV_CM2[cls - 1] * oc2 / (omega ** 2 * (omega ** 2 + oc2))


def synthesis_size(length_m: float, dx_m: float, lmax_m: float) -> int:
    """FFT size N (a power of two): period N dx covers the track and at least 4 longest waves."""
    return 1 << int(np.ceil(np.log2(max(length_m, 4.0 * lmax_m) / dx_m + 1)))


def synthesize(psd: Psd, length_m: float, dx_m: float, seed: int | None = 0,
               wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS
               ) -> tuple[np.ndarray, np.ndarray]:
    """Random profile with one-sided spectrum ``psd`` (m^2/(rad/m)) over ``wavelength_range`` (m).

    Returns x (m, from 0 to >= length_m in steps of dx_m) and u (m). Frequencies outside the
    range get zero amplitude (a sharp band-pass). Period: ``synthesis_size(...) * dx_m``.
    """
    lmin, lmax = (float(v) for v in wavelength_range)
    if not (length_m > 0 and dx_m > 0):
        raise ConfigError(f'profile: length and dx must be positive, got {length_m}, {dx_m}')
    if not (2 * dx_m <= lmin < lmax < np.inf):
        raise ConfigError(f'wavelength_range: need 2*dx <= lmin < lmax < inf, got {lmin}, {lmax} '
                          f'with dx {dx_m}')
    n_fft = synthesis_size(length_m, dx_m, lmax)
    u = spectral_period(psd, n_fft, dx_m, np.random.default_rng(seed), (lmin, lmax))
    n = int(np.ceil(length_m / dx_m - 1e-9)) + 1
    return np.arange(n) * dx_m, u[:n]


def spectral_period(psd: Psd, n_fft: int, dx_m: float, rng: np.random.Generator,
                    wavelength_range: tuple[float, float]) -> np.ndarray:
    """One period (n_fft samples of step dx_m, m) of the spectral representation sum."""
    lmin, lmax = wavelength_range
    d_omega = 2 * np.pi / (n_fft * dx_m)
    omega = np.arange(n_fft // 2 + 1) * d_omega
    inside = (omega >= 2 * np.pi / lmax) & (omega <= 2 * np.pi / lmin)
    amp = np.zeros_like(omega)
    amp[inside] = np.sqrt(2.0 * psd(omega[inside]) * d_omega)
    phase = rng.uniform(0.0, 2 * np.pi, omega.size)
    # irfft returns (1/N) sum_k X_k e^{i k n 2pi/N} over both half-spectra: X_k = N/2 A_k e^{i phi}
    return fft.irfft(0.5 * n_fft * amp * np.exp(1j * phase), n=n_fft)


# --- isolated defects -------------------------------------------------------------------------


def cosine_dip(x: np.ndarray, start: float, length: float, depth: float) -> np.ndarray:
    """Cosine dip (m) of ``depth`` m over [start, start + length] m; deepest at the middle."""
    s = (np.asarray(x, dtype=float) - start) / length
    inside = (s >= 0) & (s <= 1)
    return np.where(inside, -0.5 * depth * (1 - np.cos(2 * np.pi * s)), 0.0)


# Default (length m, depth m): dipped joint 3 mm over 1 m (Kabo 2006), dipped weld 0.3 mm over
# 1 m (versine tolerance), light squat 0.2 mm over 30 mm (rail_domain.md section 2).
JOINT = (1.0, 3e-3)
WELD = (1.0, 3e-4)
SQUAT = (0.03, 2e-4)
# Default corrugation patch: 10 m of 50 mm waves, 0.05 mm amplitude (rail_domain.md section 2).
CORRUGATION = (10.0, 0.05, 5e-5)


def dipped_joint(x: np.ndarray, start: float, length: float = JOINT[0],
                 depth: float = JOINT[1]) -> np.ndarray:
    """Dipped rail joint (m) as a cosine dip, default 3 mm over 1 m."""
    return cosine_dip(x, start, length, depth)


def dipped_weld(x: np.ndarray, start: float, length: float = WELD[0],
                depth: float = WELD[1]) -> np.ndarray:
    """Dipped weld (m) as a cosine dip, default 0.3 mm over 1 m."""
    return cosine_dip(x, start, length, depth)


def squat(x: np.ndarray, start: float, length: float = SQUAT[0],
          depth: float = SQUAT[1]) -> np.ndarray:
    """Squat surface depression (m) as a short cosine dip, default 0.2 mm over 30 mm."""
    return cosine_dip(x, start, length, depth)


def corrugation(x: np.ndarray, start: float, length: float, wavelength: float,
                amplitude: float) -> np.ndarray:
    """Corrugation patch (m): amplitude * sin over whole wavelengths starting at ``start``.

    The patch holds round(length / wavelength) (at least 1) full waves so it ends at zero.
    """
    n_waves = max(1, round(length / wavelength))
    s = np.asarray(x, dtype=float) - start
    inside = (s >= 0) & (s <= n_waves * wavelength)
    return np.where(inside, amplitude * np.sin(2 * np.pi * s / wavelength), 0.0)


# Spec keys -> (function keyword, default or None when required), per defect kind.
_DEFECT_KEYS: dict[str, dict[str, tuple[str, float | None]]] = {
    'dip': {'len': ('length', None), 'depth': ('depth', None)},
    'joint': {'len': ('length', JOINT[0]), 'depth': ('depth', JOINT[1])},
    'weld': {'len': ('length', WELD[0]), 'depth': ('depth', WELD[1])},
    'squat': {'len': ('length', SQUAT[0]), 'depth': ('depth', SQUAT[1])},
    'corrugation': {'len': ('length', CORRUGATION[0]), 'wl': ('wavelength', CORRUGATION[1]),
                    'amp': ('amplitude', CORRUGATION[2])},
}
MAX_DEFECT_SIZE_M = 0.1  # deeper dips / larger amplitudes are unit errors (mm given as m)


@dataclass(frozen=True)
class Defect:
    """An isolated defect: kind (see ``_DEFECT_KEYS``), start chainage (m) and its parameters."""

    kind: str
    start: float
    length: float
    depth: float = 0.0
    wavelength: float = 0.0
    amplitude: float = 0.0

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The defect's displacement (m) at chainages x (m)."""
        if self.kind == 'corrugation':
            return corrugation(x, self.start, self.length, self.wavelength, self.amplitude)
        return cosine_dip(x, self.start, self.length, self.depth)

    @property
    def shortest_wavelength(self) -> float:
        """Shortest feature (m) that the simulation must resolve."""
        return self.wavelength if self.kind == 'corrugation' else self.length


def _parse_token(token: str) -> Defect:
    """One ``kind@start[:key=value...]`` token -> Defect; ConfigError naming the token."""
    match = re.fullmatch(r'\s*([a-z]+)\s*@\s*([^:]+?)\s*((?::[^:]*)*)', token)
    if not match or match.group(1) not in _DEFECT_KEYS:
        raise ConfigError(f'defects: cannot parse {token!r}; expected KIND@START[:key=value...] '
                          f'with KIND in {", ".join(_DEFECT_KEYS)}')
    kind, keys = match.group(1), _DEFECT_KEYS[match.group(1)]
    values = {}
    for item in ['start=' + match.group(2)] + [i for i in match.group(3).split(':') if i]:
        key, sep, text = item.partition('=')
        key = key.strip()
        if not sep or (key not in keys and key != 'start'):
            raise ConfigError(f'defects: {token!r}: unknown or malformed {item!r}; keys for '
                              f'{kind}: {", ".join(keys)}')
        try:
            value = float(text)
        except ValueError:
            raise ConfigError(f'defects: {token!r}: {key} is not a number: {text!r}') from None
        if not np.isfinite(value) or (key != 'start' and value <= 0):
            raise ConfigError(f'defects: {token!r}: {key} must be a positive number (m)')
        values[key] = value
    kwargs: dict[str, float] = {}
    for key, (name, default) in keys.items():
        given = values.get(key, default)
        if given is None:
            raise ConfigError(f'defects: {token!r}: missing {key}= (m)')
        kwargs[name] = given
    size = kwargs.get('depth', kwargs.get('amplitude', 0.0))
    if size > MAX_DEFECT_SIZE_M:
        raise ConfigError(f'defects: {token!r}: {size} m is not a plausible size; values are in '
                          f'metres (8 mm = 8e-3)')
    if kind == 'corrugation' and kwargs['wavelength'] > kwargs['length']:
        raise ConfigError(f'defects: {token!r}: wl must not exceed len')
    return Defect(kind, values['start'], **kwargs)


def parse_defects(spec: str | None) -> list[Defect]:
    """Parse a comma-separated defects spec, e.g. ``dip@500:len=6:depth=8e-3,joint@800``.

    Each token is ``KIND@START[:key=value...]`` in metres; see docs/simulation.md.
    """
    if spec is None or not spec.strip():
        return []
    return [_parse_token(token) for token in spec.split(',')]


def apply_defects(x: np.ndarray, u: np.ndarray, defects: list[Defect] | str | None
                  ) -> np.ndarray:
    """Return u (m) plus every defect evaluated at chainages x (m); defects list or spec."""
    if isinstance(defects, str) or defects is None:
        defects = parse_defects(defects)
    u = np.array(u, dtype=float)
    for defect in defects:  # a handful of defects, each vectorised over x
        u += defect(x)
    return u


# --- deterministic and file profiles ----------------------------------------------------------

# Paper demonstration profile: Ricker ("Mexican hat") wavelets, each with zero mean and zero
# running area once passed. Centre (m), peak displacement (m), width sigma (m); the deepest one
# at 70 m (t = 7 s at 10 m/s). Spectral peak of a Ricker at wavelength pi sqrt(2) sigma: 9-18 m,
# inside D1.
PAPER_WAVELETS = np.array([[25.0, 1.5e-3, 2.0],
                           [70.0, -4.0e-3, 3.0],
                           [115.0, 2.0e-3, 4.0]])


def paper_profile(x_m: np.ndarray) -> np.ndarray:
    """The demonstration profile (m): zero mean, smooth, deepest (-4 mm) at 70 m.

    Zero mean matters: the paper's feedback inversion (K = 1000) leaves an error of about
    (area under the profile) * t / K, so a profile with nonzero mean cannot be reconstructed to
    1e-3. Each Ricker wavelet integrates to zero, and so does its running area once it is passed.
    """
    x = np.asarray(x_m, dtype=float)[..., None]
    centre, peak, sigma = PAPER_WAVELETS.T
    s2 = ((x - centre) / sigma) ** 2
    return np.sum(peak * (1 - s2) * np.exp(-0.5 * s2), axis=-1)


def _csv_error(path: Path, line: int, what: str) -> ConfigError:
    return ConfigError(f'{path}:{line}: {what}')


def load_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a profile CSV with header ``x_m,u_m`` (metres); x strictly increasing.

    Unreadable, malformed or non-monotonic files raise ConfigError naming the file and line.
    """
    path = Path(path)
    try:
        with path.open(newline='', encoding='utf-8') as handle:
            rows = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f'{path}: cannot read profile CSV ({exc})') from None
    if not rows or [c.strip() for c in rows[0]] != ['x_m', 'u_m']:
        raise _csv_error(path, 1, 'expected the header x_m,u_m')
    body = [(i + 1, row) for i, row in enumerate(rows) if i > 0 and any(c.strip() for c in row)]
    if len(body) < 2:
        raise _csv_error(path, len(rows), 'a profile needs at least two data rows')
    for line, row in body:
        if len(row) != 2:
            raise _csv_error(path, line, f'expected two columns, got {",".join(row)!r}')
    try:
        data = np.array([row for _, row in body], dtype=float)
    except ValueError:
        # slow path only to name the first bad line
        for line, row in body:
            try:
                [float(c) for c in row]
            except ValueError:
                raise _csv_error(path, line, f'not a number in {",".join(row)!r}') from None
        raise
    lines = np.array([line for line, _ in body])
    bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
    if bad.size:
        raise _csv_error(path, int(lines[bad[0]]), 'value is not finite')
    step = np.flatnonzero(np.diff(data[:, 0]) <= 0)
    if step.size:
        raise _csv_error(path, int(lines[step[0] + 1]), 'x_m must increase strictly')
    return data[:, 0].copy(), data[:, 1].copy()


def save_csv(path: str | Path, x_m: np.ndarray, u_m: np.ndarray) -> None:
    """Write a profile CSV with header ``x_m,u_m`` (full float precision)."""
    np.savetxt(path, np.column_stack([x_m, u_m]), delimiter=',', header='x_m,u_m',
               comments='', fmt='%.17g')


def spectrum_for(spec: str) -> Psd:
    """The spectrum named by a profile spec ``german-low|german-high|fra-N``."""
    if spec in ('german-low', 'german-high'):
        return partial(german_psd, level=spec.split('-')[1])
    match = re.fullmatch(r'fra-([1-6])', spec)
    if match:
        return partial(fra_psd, cls=int(match.group(1)))
    raise ConfigError(f'profile: unknown {spec!r}; expected german-low, german-high, fra-1..6, '
                      f'paper or file:PATH.csv')


def make_profile(spec: str, length_m: float, dx_m: float, seed: int | None = 0,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Profile (x_m, u_m) on a uniform grid of step dx_m covering length_m.

    ``spec``: german-low | german-high | fra-1..6 (random, seeded) | paper | file:PATH.csv. A
    CSV profile keeps its own chainage origin, is linearly interpolated and must cover length_m.
    """
    n = int(np.ceil(length_m / dx_m - 1e-9)) + 1
    if spec == 'paper':
        x = np.arange(n) * dx_m
        return x, paper_profile(x)
    if spec.startswith('file:'):
        path = Path(spec[5:])
        xc, uc = load_csv(path)
        x = xc[0] + np.arange(n) * dx_m
        if x[-1] > xc[-1] + 1e-9:
            raise ConfigError(f'{path}: covers {xc[-1] - xc[0]:g} m, the run needs {length_m:g} m')
        return x, np.interp(x, xc, uc)
    return synthesize(spectrum_for(spec), length_m, dx_m, seed, wavelength_range)


# --- profiles along a whole line, evaluated at any chainage ----------------------------------

LINE_GRID_PER_LMIN = 32  # line grid step lmin / 32: linear interpolation loses < 0.4 % at lmin
LINE_TILE_WAVES = 8  # a tile spans at least 8 longest wavelengths
LINE_TILE_CACHE = 4  # tiles kept: a chunk of a run touches two or three
_TILE_KEY_OFFSET = 2 ** 40  # spawn keys are non-negative: tiles j > -2^40 (any real chainage)


class RandomLine:
    """A random profile along a whole line: the same u at a chainage whatever the run.

    Tiles j = ..., -1, 0, 1, ... of period 2S (S = tile spacing) hold independent spectral
    representation sums (``spectral_period``, from the seed and j), each weighted by the sine
    window sin(pi s / 2S) over its span [jS, jS + 2S]. Two tiles overlap everywhere and
    cos^2 + sin^2 = 1, so the variance is exactly the spectrum's and the profile never repeats;
    the window widens every spectral line by about 1 / (2S) cycles/m (S >= 4 lmax: below 1/8 of
    the lowest frequency). Values between grid points (step lmin / 32) are linear.
    """

    def __init__(self, psd: Psd, seed: int | None = 0,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS) -> None:
        lmin, lmax = (float(v) for v in wavelength_range)
        if not (0 < lmin < lmax < np.inf):
            raise ConfigError(f'wavelength_range: need 0 < lmin < lmax < inf, got {lmin}, {lmax}')
        self.psd = psd
        self.wavelength_range = (lmin, lmax)
        self.dx = lmin / LINE_GRID_PER_LMIN
        self.n_fft = synthesis_size(LINE_TILE_WAVES * lmax, self.dx, lmax)
        self.spacing_m = 0.5 * self.n_fft * self.dx
        self.entropy = np.random.SeedSequence(seed).entropy
        self._grid = np.arange(self.n_fft + 1) * self.dx
        self._tiles: dict[int, np.ndarray] = {}

    def tile(self, j: int) -> np.ndarray:
        """Tile j on its grid (n_fft + 1 samples: the period closed), m."""
        if j not in self._tiles:
            if len(self._tiles) >= LINE_TILE_CACHE:
                self._tiles.pop(next(iter(self._tiles)))
            seq = np.random.SeedSequence(self.entropy, spawn_key=(j + _TILE_KEY_OFFSET,))
            u = spectral_period(self.psd, self.n_fft, self.dx, np.random.default_rng(seq),
                                self.wavelength_range)
            self._tiles[j] = np.append(u, u[0])
        return self._tiles[j]

    def __call__(self, x_m: np.ndarray) -> np.ndarray:
        """Irregularity (m) at chainages x_m (m), any shape."""
        x = np.asarray(x_m, dtype=float)
        pos = x / self.spacing_m
        j = np.floor(pos)
        theta = 0.5 * np.pi * (pos - j)
        u = np.empty_like(x)
        for jj in np.unique(j).astype(np.int64).tolist():  # two or three tiles per chunk
            mine = j == jj
            local = x[mine] - jj * self.spacing_m
            older = np.interp(local + self.spacing_m, self._grid, self.tile(jj - 1))
            newer = np.interp(local, self._grid, self.tile(jj))
            u[mine] = np.cos(theta[mine]) * older + np.sin(theta[mine]) * newer
        return u


@dataclass(frozen=True)
class FileLine:
    """A profile CSV as a line: linear between its points, an error outside them."""

    path: Path
    x_m: np.ndarray
    u_m: np.ndarray

    def __call__(self, x_m: np.ndarray) -> np.ndarray:
        """Irregularity (m) at chainages x_m (m) inside the file's range."""
        x = np.asarray(x_m, dtype=float)
        if x.size and (x.min() < self.x_m[0] - 1e-9 or x.max() > self.x_m[-1] + 1e-9):
            raise ConfigError(f'{self.path}: covers {self.x_m[0]:g}-{self.x_m[-1]:g} m, the run '
                              f'needs {x.min():g}-{x.max():g} m')
        return np.interp(x, self.x_m, self.u_m)


LineProfile = Callable[[np.ndarray], np.ndarray]


def line_profile(spec: str, seed: int | None = 0,
                 wavelength_range: tuple[float, float] = DEFAULT_WAVELENGTHS
                 ) -> tuple[LineProfile, float]:
    """(u(x) for any chainage array x in m, natural origin in m) for a profile spec.

    german-low|german-high|fra-N: ``RandomLine`` (origin 0); paper: ``paper_profile`` (origin
    0); file:PATH.csv: ``FileLine`` (origin: the file's first chainage).
    """
    if spec == 'paper':
        return paper_profile, 0.0
    if spec.startswith('file:'):
        path = Path(spec[5:])
        x, u = load_csv(path)
        return FileLine(path, x, u), float(x[0])
    return RandomLine(spectrum_for(spec), seed, wavelength_range), 0.0
