"""EN 13848-5 quality levels of longitudinal level for isolated defects and 200 m sections.

Values: EN 13848-5:2008+A1:2010 as commonly reproduced in secondary sources, NOT checked against
the standard's text (docs/review.md and rail_domain.md section 1, tag [M]). Isolated defects are
mean-to-peak values of the band-filtered signal (D1: 3-25 m, D2: 25-70 m). The standard gives
ranges for the alert (AL) and intervention (IL) limits, within which the infrastructure manager
chooses; the immediate-action limit (IAL) is one value. The 200 m standard deviations are the
informative annex's AL range for D1.

Speed classes by the upper bound in km/h: v <= 80, 80 < v <= 120, ..., 230 < v <= 300; above
300 km/h the table does not apply (no limits).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from railgsa_ros.errors import ConfigError

SOURCE = ('EN 13848-5:2008+A1:2010 as reproduced in secondary sources, not checked against the '
          'standard text [M]')
LEVELS = ('AL', 'IL', 'IAL')  # alert, intervention, immediate action, in rising severity
ENDS = ('lower', 'upper')
CLASS_UPPER_KMH = np.array([80.0, 120.0, 160.0, 230.0, 300.0])
MM = 1e-3
NAN = float('nan')

# D1 isolated defects, mm: (AL range, IL range, IAL) per speed class [M]
_D1_MM = (((12, 18), (17, 21), 28), ((8, 12), (10, 17), 26), ((6, 10), (8, 14), 23),
          ((5, 9), (7, 12), 20), ((4, 8), (6, 10), 16))
# D2: IAL only above 160 km/h [M]; no AL/IL in the table
_D2_IAL_MM = (NAN, NAN, NAN, 33.0, 28.0)
# D1 standard deviation over 200 m, AL range in mm (informative annex) [M]
_SD_MM = ((2.3, 3.0), (1.8, 2.7), (1.4, 2.4), (1.2, 1.9), (1.0, 1.5))


def class_label(index: int) -> str:
    """'v <= 80 km/h', '80 < v <= 120 km/h', ... or 'v > 300 km/h' (index -1)."""
    if index < 0 or index >= CLASS_UPPER_KMH.size:
        return f'v > {CLASS_UPPER_KMH[-1]:.0f} km/h'
    if index == 0:
        return f'v <= {CLASS_UPPER_KMH[0]:.0f} km/h'
    return f'{CLASS_UPPER_KMH[index - 1]:.0f} < v <= {CLASS_UPPER_KMH[index]:.0f} km/h'


def speed_class(speed_mps: np.ndarray) -> np.ndarray:
    """Speed class index per speed (m/s, sign ignored): 0..4, -1 above 300 km/h or not finite."""
    kmh = np.round(np.abs(np.asarray(speed_mps, dtype=float)) * 3.6, 6)  # 120 / 3.6 * 3.6 > 120
    idx = np.searchsorted(CLASS_UPPER_KMH, kmh, side='left')
    return np.where((idx < CLASS_UPPER_KMH.size) & np.isfinite(kmh), idx, -1)


@dataclass(frozen=True)
class Limits:
    """Isolated-defect limits (C, 3) in m (columns AL, IL, IAL; NaN where the table has none)
    and the 200 m SD alert range (C, 2) in m, for C speed classes, one band and one range end."""

    band: str
    end: str
    isolated_m: np.ndarray
    sd_range_m: np.ndarray

    def at(self, speed_mps: np.ndarray) -> np.ndarray:
        """Per-sample thresholds (K, 3) in m for speeds (K,); NaN rows above 300 km/h."""
        idx = speed_class(speed_mps)
        table = np.vstack([self.isolated_m, np.full((1, 3), NAN)])
        return table[idx]  # index -1 picks the NaN row

    def sd_at(self, speed_mps: np.ndarray) -> np.ndarray:
        """200 m SD alert range (S, 2) in m for section speeds (S,); NaN above 300 km/h or D2."""
        table = np.vstack([self.sd_range_m, np.full((1, 2), NAN)])
        return table[speed_class(speed_mps)]


def en13848_limits(band: str = 'd1', end: str = 'lower') -> Limits:
    """The EN 13848-5 table for ``band`` ('d1' or 'd2') taking the ``end`` ('lower': the
    strictest value an infrastructure manager may choose, the default for screening a
    reconstruction; 'upper': the most lenient) of the AL and IL ranges."""
    if end not in ENDS:
        raise ConfigError(f'limit end: expected lower or upper, got {end!r}')
    pick = ENDS.index(end)
    if band == 'd1':
        isolated = np.array([[al[pick], il[pick], ial] for al, il, ial in _D1_MM], dtype=float)
        sd = np.array(_SD_MM, dtype=float)
    elif band == 'd2':
        isolated = np.column_stack([np.full(5, NAN), np.full(5, NAN), _D2_IAL_MM])
        sd = np.full((5, 2), NAN)
    else:
        raise ConfigError(f'band: EN 13848-5 limits exist for d1 and d2, not {band!r}')
    return Limits(band, end, isolated * MM, sd * MM)
