"""Per-sample records and how much of a run is in memory at once (no ROS).

A record is a dataclass of arrays whose LAST axis is the sample (``inverse.pipeline.Output``,
``uncertainty.Band``, ``inverse.grid.GridOutput``, ``offline.Step``; a bank's (P, K) outputs
included); ``join``, ``take`` and ``split`` are the one concatenation, selection and cut of such
records. ``CHUNK`` is the one size of
an offline piece: ``bag.reader.iter_imu`` reads pieces of it and ``uncertainty.offline_bands``
feeds in-memory streams in pieces of it. One exception: ``review.stream.REVIEW_CHUNK`` (16,384
samples), the pieces ``railgsa review`` reads, smaller against heap fragmentation (the review
keeps no per-sample array; docs/review.md, Memory).
"""

from __future__ import annotations

from collections.abc import Sequence, Sized
from dataclasses import fields, replace
from typing import Any, TypeVar

import numpy as np

#: Samples per offline piece: 65 s at 1 kHz, 0.5 MB per float64 column.
CHUNK = 65536


R = TypeVar('R', bound=Sized)  # a record: a dataclass whose len() is its sample count


def join(parts: Sequence[R], empty: R) -> R:
    """The records in order as one (along the last axis of every field; a field None in any
    part is None); ``empty`` when no part has a sample."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return empty
    if len(parts) == 1:
        return parts[0]
    first: Any = parts[0]
    columns = {f.name: [getattr(p, f.name) for p in parts] for f in fields(first)}
    return replace(first, **{name: None if any(c is None for c in cols)
                                else np.concatenate(cols, axis=-1)
                                for name, cols in columns.items()})


def take(record: R, index: slice | np.ndarray) -> R:
    """The samples ``index`` (a slice, a boolean mask or indices) of a record, in every field
    (records nested in it too; None stays None)."""
    whole: Any = record

    def pick(value: Any) -> Any:
        if value is None:
            return None
        if isinstance(value, np.ndarray):
            return value[..., index]
        return take(value, index)  # a nested record
    return replace(whole, **{f.name: pick(getattr(whole, f.name)) for f in fields(whole)})


def split(record: R, count: int) -> tuple[R, R]:
    """The first ``count`` samples of a record and the rest."""
    return take(record, slice(None, count)), take(record, slice(count, None))


def pieces(size: int, chunk: int = CHUNK) -> list[slice]:
    """Consecutive slices of at most ``chunk`` samples covering ``size`` samples."""
    return [slice(lo, lo + chunk) for lo in range(0, size, chunk)]
