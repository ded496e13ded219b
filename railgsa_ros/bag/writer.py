"""Writing rosbag2 bags (metadata.yaml + one .mcap or .db3 file) atomically with rosbags (MCAP:
``mcap_storage``, whole blocks of messages at once)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin

from railgsa_ros.bag.mcap_storage import RosbagWriter
from railgsa_ros.bag.messages import typestore
from railgsa_ros.errors import ConfigError
from railgsa_ros.fileio import atomic_output
from railgsa_ros.qos import record_qos

STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}

Batch = tuple[np.ndarray, np.ndarray | Sequence[bytes]]  # log times (N,), (N, L) uint8 or bytes


class BagWriter:
    """A rosbag2 writer for arbitrary message types, used as a context manager.

    The bag is built in a temporary directory next to ``path`` and renamed into place when the
    ``with`` block ends without error; on error nothing is left behind. ``compression='zstd'``
    compresses MCAP chunks (storage-level compression, as ``ros2 bag record
    --compression-format zstd`` with the MCAP plugin); sqlite3 bags are written uncompressed.
    """

    def __init__(self, path: str | Path, storage: str = 'mcap', compression: str | None = None,
                 overwrite: bool = False) -> None:
        if storage not in STORAGES:
            raise ConfigError(f'storage: expected one of {", ".join(STORAGES)}, got {storage!r}')
        if compression not in (None, 'zstd'):
            raise ConfigError(f'compression: expected zstd or none, got {compression!r}')
        if compression and storage != 'mcap':
            raise ConfigError('compression: zstd needs the mcap storage')
        self.path = Path(path)
        self.storage = storage
        self.compression = compression
        self.overwrite = overwrite
        self._stack: ExitStack | None = None
        self._writer: RosbagWriter | None = None
        self._connections: dict[str, Connection] = {}

    def __enter__(self) -> BagWriter:
        with ExitStack() as stack:
            tmp = stack.enter_context(atomic_output(self.path, self.overwrite))
            writer = RosbagWriter(tmp, version=9, storage_plugin=STORAGES[self.storage])
            if self.compression:
                writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer = stack.enter_context(writer)
            self._stack = stack.pop_all()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        stack, self._stack, self._writer = self._stack, None, None
        if stack is not None:
            stack.__exit__(exc_type, exc, tb)

    def add_topic(self, topic: str, msgtype: str, offered_qos: Qos | None = None) -> None:
        """Declare a topic; the default offered QoS is RELIABLE, KEEP_LAST 10."""
        writer = self._open()
        if topic in self._connections:
            raise ConfigError(f'{self.path}: topic {topic} added twice')
        self._connections[topic] = writer.add_connection(
            topic, msgtype, typestore=typestore(),
            offered_qos_profiles=[offered_qos or record_qos(True, 10)])

    def write(self, topic: str, log_time_ns: int, msg: Any) -> None:
        """Write one message: serialised CDR bytes or a rosbags message object."""
        conn = self._connections[topic]
        if not isinstance(msg, (bytes, bytearray, memoryview)):
            msg = typestore().serialize_cdr(msg, conn.msgtype)
        self._open().write(conn, int(log_time_ns), msg)

    def write_batches(self, batches: Mapping[str, Batch]) -> None:
        """Write serialised messages of several topics interleaved in log-time order (stable:
        topic order, then message order, on ties), as a recorder would; ``batches`` maps topic
        -> (log_times_ns (N,), messages: (N, L) uint8 rows, as ``cdr.encode_rows``, or a
        sequence of bytes)."""
        parts, ties = [], []
        for rank, (topic, (times, raws)) in enumerate(batches.items()):
            times = np.asarray(times, dtype=np.int64)
            for rows, at in _blocks(raws):
                parts.append((self._connections[topic], times[at], rows))
                ties.append((rank << 40) + at)
        self._open().write_parts(parts, ties)

    def _open(self) -> RosbagWriter:
        if self._writer is None:
            raise RuntimeError('BagWriter is not open')
        return self._writer


def _blocks(raws: np.ndarray | Sequence[bytes]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Messages as (rows (n, L) uint8, their indices (n,)) per message length."""
    if isinstance(raws, np.ndarray):
        return [(raws, np.arange(raws.shape[0]))]
    lengths = np.fromiter(map(len, raws), np.int64, len(raws))
    out = []
    for length in np.unique(lengths):
        at = np.flatnonzero(lengths == length)
        flat = b''.join(bytes(raws[int(i)]) for i in at)
        out.append((np.frombuffer(flat, np.uint8).reshape(at.size, int(length)), at))
    return out
