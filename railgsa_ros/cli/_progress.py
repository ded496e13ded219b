"""A tqdm progress bar on stderr over a bag's IMU messages, for the long offline commands.

Drawn only on a terminal, without ``--quiet``, and when tqdm is installed (the review extra;
without it the command runs the same, silently): a log or a pipe gets no carriage returns.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from railgsa_ros.bag import ImuStream


def imu_messages(bag: str | Path, topic: str) -> int | None:
    """How many messages ``topic`` has in the bag, from its index (nothing read; None when
    the topic is absent)."""
    from railgsa_ros.bag import open_bag

    with open_bag(bag) as reader:
        info = reader.topics.get(topic)
        return None if info is None else int(info.msgcount)


def with_progress(pieces: Iterable[ImuStream], bag: str | Path, topic: str, label: str,
                  quiet: bool = False) -> Iterator[ImuStream]:
    """``pieces`` as they are consumed, advancing a bar by each piece's IMU samples (of the
    bag's count of ``topic``) when stderr is a terminal and not ``quiet``."""
    if quiet or not sys.stderr.isatty():
        yield from pieces
        return
    try:
        from tqdm import tqdm
    except ImportError:
        yield from pieces
        return
    with tqdm(total=imu_messages(bag, topic), desc=label, unit='msg', file=sys.stderr,
              dynamic_ncols=True, leave=True) as bar:
        for piece in pieces:
            yield piece
            bar.update(int(piece.stamps_ns.size))
