"""Per-sample quality of a reconstructed irregularity sample (docs/inversion.md, "Quality").

VALID: the sample is within the documented accuracy of the method. DEGRADED: published, but
less certain (its band is widened): the band FIR window overlaps bridged (interpolated) input,
the speed is below ``min_design_speed_mps`` or above ``max_speed_mps`` (the band design is held,
so the reconstructed wavelength band is shifted), the speed across the window is off the band
design by more than ``window_speed_tolerance`` (acceleration, braking), samples were lost
between close stamps or the stamp jitter exceeds ``rate.JITTER_TOLERANCE`` periods, or the
sensor noise propagated into the band exceeds half of ``noise_limit_m``. INVALID: not a
measurement (u = NaN): standstill or too slow for the band to be observable, unknown speed, the
warm-up after a (re)start and the tail before a reset or flush (the FIR window reaches past the
segment's real samples), gravity not on the configured axis, or a sample rate that disagrees
with ``rate_hz``.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from railgsa_ros.input.sanitize import SMALL


class Quality(IntEnum):
    """Quality code of one output sample (published as PointStamped point.y)."""

    VALID = 0
    DEGRADED = 1
    INVALID = 2


_NAMES = tuple(q.name.lower() for q in Quality)  # in code order (Enum lookups are slow)


def quality_counts(quality: np.ndarray) -> dict[str, int]:
    """{'valid': n0, 'degraded': n1, 'invalid': n2} of a quality array."""
    if quality.size <= SMALL:  # a live push: list counts instead of a bincount
        codes = quality.tolist()
        return dict(zip(_NAMES, (codes.count(0), codes.count(1), codes.count(2)), strict=True))
    counts = np.bincount(np.asarray(quality, dtype=np.int64), minlength=3)
    return dict(zip(_NAMES, counts[:3].tolist(), strict=True))
