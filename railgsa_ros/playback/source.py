"""Opening any rosbag2 bag for raw replay, with one-line errors that name the file.

Accepted: a bag directory with ``metadata.yaml`` (one or more ``.mcap`` or ``.db3`` files, MCAP
chunks plain, zstd or lz4), a directory of storage files without ``metadata.yaml``, or a bare
``.mcap`` / ``.db3`` file. Messages come out as CDR bytes in timestamp order; malformed ones
(empty, truncated) are counted and skipped, never forwarded.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
import heapq
from pathlib import Path
import sqlite3

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import Reader, ReaderError

from railgsa_ros.bag import cdr
from railgsa_ros.bag.messages import LAYOUTS, typestore
from railgsa_ros.bag.reader import storage_paths
from railgsa_ros.errors import InputError

#: Errors that rosbags and the storage libraries raise for unreadable or damaged files.
_READ_ERRORS = (ReaderError, OSError, sqlite3.Error, ValueError, KeyError, EOFError, RuntimeError)


@dataclass
class TopicInfo:
    """One topic of a bag: type, recorded QoS, message count and the span (int64 ns) of the
    storage files that hold it."""

    name: str
    msgtype: str
    count: int = 0
    offered_qos: list[Qos] = field(default_factory=list)
    start_ns: int = 0
    end_ns: int = 0

    @property
    def rate_hz(self) -> float:
        """Mean message rate over the topic's span (Hz); 0 for fewer than two messages."""
        span = self.end_ns - self.start_ns
        return (self.count - 1) * 1e9 / span if self.count > 1 and span > 0 else 0.0


class BagSource:
    """Raw, time-ordered access to the messages of one bag; use as a context manager."""

    def __init__(self, path: str | Path) -> None:
        """Open the bag at ``path``; InputError naming the file if it is missing or unreadable."""
        self.path = Path(path)
        self._readers: list[Reader] = []
        self.malformed: dict[str, int] = {}  # topic -> malformed messages skipped
        try:
            for item in storage_paths(self.path):
                reader = Reader(item)
                self._readers.append(reader)
                reader.open()
        except _READ_ERRORS as exc:
            self.close()
            raise InputError(f'{self.path}: cannot read bag ({_reason(exc)})') from None
        self.topics = self._topic_table()
        if not any(t.count for t in self.topics.values()):
            self.close()
            raise InputError(f'{self.path}: bag has no messages')

    def _topic_table(self) -> dict[str, TopicInfo]:
        """Topics keyed by name; a topic recorded with several types keeps the first one."""
        topics: dict[str, TopicInfo] = {}
        for reader in self._readers:
            start, end = reader.start_time, reader.end_time - 1
            for conn in reader.connections:
                info = topics.setdefault(conn.topic, TopicInfo(conn.topic, conn.msgtype))
                if conn.msgtype != info.msgtype:
                    continue
                if isinstance(conn.ext, ConnectionExtRosbag2):
                    info.offered_qos.extend(conn.ext.offered_qos_profiles)
                if conn.msgcount:
                    first = not info.count
                    info.count += conn.msgcount
                    info.start_ns = start if first else min(info.start_ns, start)
                    info.end_ns = end if first else max(info.end_ns, end)
        return topics

    @property
    def start_ns(self) -> int:
        """Timestamp of the earliest message (ns)."""
        return min(t.start_ns for t in self.topics.values() if t.count)

    @property
    def end_ns(self) -> int:
        """Timestamp of the latest message (ns)."""
        return max(t.end_ns for t in self.topics.values() if t.count)

    def messages(self, topics: Sequence[str], start_ns: int | None = None,
                 stop_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """(topic, timestamp ns, CDR bytes) for ``topics`` with start_ns <= t < stop_ns, in
        timestamp order; InputError naming the file if the data turns out damaged. Malformed
        messages (``well_formed``) are skipped and counted in ``malformed`` (topic -> count)."""
        wanted = {name: self.topics[name].msgtype for name in topics}
        streams = [self._stream(r, wanted, start_ns, stop_ns) for r in self._readers]
        try:
            for topic, stamp, data in heapq.merge(*streams, key=lambda item: item[1]):
                if well_formed(wanted[topic], data):
                    yield topic, stamp, data
                else:
                    self.malformed[topic] = self.malformed.get(topic, 0) + 1
        except _READ_ERRORS as exc:
            raise InputError(f'{self.path}: damaged bag data ({_reason(exc)})') from None

    @staticmethod
    def _stream(reader: Reader, wanted: dict[str, str], start_ns: int | None,
                stop_ns: int | None) -> Iterator[tuple[str, int, bytes]]:
        """One storage's messages on the wanted (topic, type) pairs."""
        conns: list[Connection] = [c for c in reader.connections
                                   if wanted.get(c.topic) == c.msgtype]
        if not conns:
            return
        for conn, stamp, data in reader.messages(conns, start_ns, stop_ns):
            yield conn.topic, stamp, bytes(data)

    def close(self) -> None:
        """Close every open storage."""
        for reader in self._readers:
            if reader.is_open:
                reader.close()
        self._readers = []

    def __enter__(self) -> BagSource:
        """Context manager: the source itself."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close on exit."""
        self.close()


def well_formed(msgtype: str, data: bytes) -> bool:
    """Whether a message can be deserialised (a 0-byte or truncated one would make a subscriber
    fail to take it): the structural check of ``cdr.well_formed`` for the fixed-layout types
    (about 1 us), rosbags' deserialiser for other types it knows (about 50 us), the CDR
    encapsulation header only for types it does not know."""
    layout = LAYOUTS.get(msgtype)
    if layout is not None:
        return cdr.well_formed(layout, data)
    if len(data) < 4 or data[0] != 0 or data[1] > 3:
        return False
    try:
        typestore().deserialize_cdr(data, msgtype)
    except KeyError:  # a type rosbags does not know: the header is all we can check
        return True
    except Exception:  # rosbags raises SerdeError, struct.error, IndexError, ...
        return False
    return True


def _reason(exc: BaseException) -> str:
    """A one-line reason for a reader exception."""
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__
