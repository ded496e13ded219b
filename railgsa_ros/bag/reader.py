"""Reading rosbag2 bags written by any rosbag2 tool (MCAP or sqlite3) with rosbags.

Accepts a bag directory, a directory whose ``metadata.yaml`` is missing (its storage files are
read directly), or a bare ``.mcap``/``.db3`` file. Every failure of an unreadable, empty,
truncated or corrupt bag becomes an InputError that names the path.

The fixed-layout topics (``read_imu``, ``read_stamped``) of MCAP files take a faster path: the
``mcap`` package streams the chunks and a ``struct`` loop walks their records, keeping views of
the wanted messages' bytes for the vectorised CDR decoder. rosbags builds Python objects per
message and ``mcap``'s ``iter_messages`` several per message (measured on 630k messages: rosbags
3.0 s, ``iter_messages`` 5.6 s, this path 0.3 s). Anything the fast path cannot read goes through
rosbags as before.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from io import BytesIO
import os
from pathlib import Path
import sqlite3
import struct
from typing import Any
import warnings

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk
from mcap.stream_reader import get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC
import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection

from railgsa_ros.bag import cdr
from railgsa_ros.bag.messages import (
    IMU,
    IMU_FIELDS,
    LAYOUTS,
    ODOMETRY,
    ODOMETRY_FIELDS,
    flatten,
    typestore,
)
from railgsa_ros.config import load_yaml
from railgsa_ros.errors import ConfigError, InputError, InputWarning, RailGsaError
from railgsa_ros.samples import CHUNK  # IMU samples per piece of iter_imu

STORAGE_SUFFIXES = ('.mcap', '.db3')
_RECORD = struct.Struct('<BQ')  # MCAP record: opcode, content length
_MESSAGE = struct.Struct('<HIQQ')  # MCAP message: channel id, sequence, log and publish time
#: messages of a batch per topic: log times (N,) ns and the decoded messages (fixed layouts) or
#: their bytes (the others, and everything rosbags reads)
Body = cdr.Decoded | list[bytes]
Batch = dict[str, tuple[np.ndarray, Body]]


def storage_paths(path: str | Path) -> list[Path]:
    """The paths to hand to rosbags for ``path``; InputError if it cannot be a rosbag2 bag, or
    when an MCAP file of it is unfinished (``mcap_finished``: run ``railgsa recover``)."""
    path = Path(path)
    if path.is_file() and path.name == 'metadata.yaml':
        path = path.parent
    if path.is_file():
        if path.suffix not in STORAGE_SUFFIXES:
            raise InputError(f'{path}: not a rosbag2 bag (expected a directory, .mcap or .db3)')
        _refuse_unfinished(path, [path])
        _apply_wal(path, [path])
        return [path]
    if not path.is_dir():
        raise InputError(f'{path}: no such bag')
    _refuse_unfinished(path, path.glob('*.mcap'))
    _apply_wal(path, path.glob('*.db3'))
    if (path / 'metadata.yaml').is_file():
        return [path]
    for suffix in STORAGE_SUFFIXES:
        files = sorted(path.glob('*' + suffix))
        if files:
            return files
    raise InputError(f'{path}: not a rosbag2 bag (no metadata.yaml, .mcap or .db3 file)')


def mcap_finished(file: Path) -> bool:
    """Whether an MCAP file ends with its footer and closing magic (its writer finished it; a
    killed recorder leaves neither)."""
    tail_size = _RECORD.size + 20 + len(MCAP0_MAGIC)  # footer record, magic
    try:
        with file.open('rb') as stream:
            size = stream.seek(0, os.SEEK_END)
            if size < len(MCAP0_MAGIC) + tail_size:
                return False
            stream.seek(size - tail_size)
            tail = stream.read()
    except OSError:
        return False
    return tail[0] == Opcode.FOOTER and tail.endswith(MCAP0_MAGIC)


def _refuse_unfinished(bag: Path, files: Iterable[Path]) -> None:
    """InputError naming ``bag`` and the first unfinished .mcap of ``files``: readers would
    miss it (not in metadata.yaml) or fail on it (no summary)."""
    for file in sorted(f for f in files if f.suffix == '.mcap'):
        if not mcap_finished(file):
            which = '' if file == bag else f'{file.name} is '
            raise InputError(f'{bag}: {which}unfinished (no MCAP footer: its recorder was '
                             f'killed?); run "railgsa recover {bag}" to make it readable')


def _apply_wal(bag: Path, files: Iterable[Path]) -> None:
    """Move the messages of each .db3's write-ahead log into it (SQLite's own checkpoint, what
    any SQLite reader does on close); InputError naming ``bag`` when that cannot be done.

    rosbag2's resilient storage preset writes in WAL mode: until a checkpoint the newest
    messages are only in ``NAME.db3-wal``, and rosbags opens the .db3 as immutable, which
    ignores the log (31,815 of 49,876 IMU samples read, no error)."""
    for db3 in files:
        wal = db3.with_name(db3.name + '-wal')
        if db3.suffix != '.db3' or not wal.is_file() or wal.stat().st_size == 0:
            continue
        try:
            con = sqlite3.connect(f'file:{db3}?mode=rw', uri=True, timeout=5.0)
            try:
                busy, _, _ = con.execute('PRAGMA wal_checkpoint(TRUNCATE)').fetchone()
            finally:
                con.close()
        except sqlite3.Error as exc:
            busy, reason = 1, _one_line(exc)
        else:
            reason = 'a reader or writer holds it'
        if busy or (wal.is_file() and wal.stat().st_size):
            raise InputError(f'{bag}: {wal.name} holds messages not yet in {db3.name} (written in '
                             f'WAL mode) and they cannot be applied ({reason}); copy the bag to '
                             'a writable directory and read it there')


def _one_line(exc: BaseException) -> str:
    """A short single-line description of a third-party exception."""
    text = ' '.join(str(exc).split()) or type(exc).__name__
    return text if len(text) <= 160 else text[:157] + '...'


@contextmanager
def open_bag(path: str | Path) -> Iterator[AnyReader]:
    """An open rosbags AnyReader; any failure inside the block becomes InputError naming ``path``
    (a RailGsaError passes through unchanged)."""
    try:
        with AnyReader(storage_paths(path), default_typestore=typestore()) as reader:
            yield reader
    except RailGsaError:
        raise
    except Exception as exc:  # rosbags/zstd/sqlite raise many types for a damaged file
        raise InputError(f'{path}: unreadable bag ({_one_line(exc)})') from None


def read_messages(path: str | Path,
                  topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, Any]]:
    """Yield (topic, log_time_ns, message) in log-time order, deserialised with the bag's own
    message definitions; ``topics=None`` reads all topics."""
    with open_bag(path) as reader:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, log_time, raw in reader.messages(connections=conns):
            yield conn.topic, log_time, reader.deserialize(raw, conn.msgtype)


@dataclass(frozen=True)
class TopicData:
    """One topic decoded as arrays: log times (N,), header stamps (N,) ns, strings, bodies."""

    log_time_ns: np.ndarray
    stamps_ns: np.ndarray
    strings: tuple[np.ndarray, ...]
    values: np.ndarray


def _topic_connections(reader: AnyReader, path: Path, topic: str,
                       msgtype: str) -> list[Connection]:
    """Connections of ``topic``; InputError when it is absent or of another type."""
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
        raise InputError(f'{path}: no topic {topic} (topics: {have})')
    wrong = sorted({c.msgtype for c in conns} - {msgtype})
    if wrong:
        raise InputError(f'{path}: topic {topic} has type {wrong[0]}, expected {msgtype}')
    return conns


def _mcap_files(path: Path) -> list[Path] | None:
    """The storage files of ``path`` when all of them are uncompressed-file MCAP (the files a
    bag's metadata.yaml lists, else every .mcap of a directory), else None."""
    files = []
    for entry in storage_paths(path):
        if entry.is_dir() and (entry / 'metadata.yaml').is_file():
            try:
                info = load_yaml(entry / 'metadata.yaml')['rosbag2_bagfile_information']
                found = [entry / name for name in info['relative_file_paths']]
            except (ConfigError, KeyError, TypeError):
                return None  # rosbags decides and reports
        elif entry.is_dir():
            found = sorted(entry.glob('*.mcap'))
            if any(entry.glob('*.db3')):
                return None
        else:
            found = [entry]
        if not found or any(f.suffix != '.mcap' for f in found):
            return None
        files += found
    return files


class _McapTopics:
    """Messages of some topics (topic -> message type with a fixed layout) of MCAP files,
    decoded chunk by chunk through the chunks' message indexes: per topic a list of (log times
    (n,), file-order keys (n,), cdr.Decoded) pieces. Chunks are decompressed only when they hold
    a wanted message; ValueError when a message is not plain CDR.

    The record walks are ``struct`` loops of our own, the records are decoded by ``mcap``:
    ``mcap.StreamReader`` parses every message index entry into Python objects (1.3 s of a
    600 s, 1 kHz bag), ``iter_messages`` builds objects per message (5.6 s), rosbags too (3.0 s);
    this takes 0.3 s (measured).
    """

    def __init__(self, wanted: dict[str, str]) -> None:
        self.layouts = {topic: LAYOUTS[msgtype] for topic, msgtype in wanted.items()}
        self.pieces: dict[str, list[tuple[np.ndarray, np.ndarray, cdr.Decoded]]] = {
            t: [] for t in wanted}
        self.wanted = set(wanted)  # topics whose messages are kept
        self._records = 0  # top-level records read: file order of chunks and messages

    def read(self, file: Path) -> None:
        """Add the wanted messages of one MCAP file (read record by record: a chunk at a time
        in memory)."""
        for _ in self.chunks(file):
            pass

    def chunks(self, file: Path) -> Iterator[None]:
        """``read`` one chunk at a time: yields after each chunk's messages were added."""
        self._dest: dict[int, str] = {}  # channel id -> wanted topic
        self._known: set[int] = set()  # every channel id seen
        with file.open('rb') as stream:
            magic = len(MCAP0_MAGIC)
            if stream.read(magic) != MCAP0_MAGIC:
                raise ValueError('not an MCAP file')
            footer = stream.seek(0, os.SEEK_END) - magic - _RECORD.size - 20
            stream.seek(footer)
            tail = stream.read(_RECORD.size + 20)
            summary = struct.unpack_from('<Q', tail, _RECORD.size)[0]
            if tail[0] == Opcode.FOOTER and summary:  # channels repeated in the summary
                stream.seek(summary)
                self._walk(stream.read(footer - summary), 0, footer - summary, -1)
            stream.seek(magic)
            chunk: tuple[Chunk, dict[int, np.ndarray]] | None = None
            while header := stream.read(_RECORD.size):
                opcode, length = _RECORD.unpack(header)
                if opcode == Opcode.MESSAGE_INDEX and chunk is not None:
                    data = stream.read(length)
                    channel, size = struct.unpack_from('<HI', data)
                    # (log time, offset in the chunk's records) per message
                    chunk[1][channel] = np.frombuffer(data, '<u8', size // 8, 6).reshape(-1, 2)
                    continue
                if chunk is not None:
                    self._chunk(*chunk)
                    chunk = None
                    yield
                self._records += 1
                if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    break  # the summary section follows: nothing more to read
                if opcode == Opcode.CHUNK:
                    chunk = (Chunk.read(ReadDataStream(BytesIO(stream.read(length)))), {})
                elif opcode in (Opcode.CHANNEL, Opcode.MESSAGE):  # outside the chunks
                    record = header + stream.read(length)
                    self._walk(record, 0, len(record), self._records)
                else:
                    stream.seek(length, os.SEEK_CUR)
            if chunk is not None:
                self._chunk(*chunk)
                yield

    def _walk(self, data: bytes, pos: int, end: int, key: int) -> None:
        """Channels and messages of the records in data[pos:end], one at a time; ``key``: file
        order of the chunk (-1: keep no message)."""
        while pos < end:
            opcode, length = _RECORD.unpack_from(data, pos)
            at = pos + _RECORD.size
            if opcode == Opcode.CHANNEL:
                channel = Channel.read(ReadDataStream(BytesIO(data[at:at + length])))
                self._known.add(channel.id)
                if channel.topic in self.wanted:
                    self._dest[channel.id] = channel.topic
            elif opcode == Opcode.MESSAGE and key >= 0:
                channel, _, log_time, _ = _MESSAGE.unpack_from(data, at)
                if channel in self._dest:
                    body = np.frombuffer(data[at + _MESSAGE.size:at + length], np.uint8)
                    self._add(self._dest[channel], np.array([log_time], np.int64),
                              np.array([key << 32 | pos]), body[None])
            pos = at + length

    def _chunk(self, chunk: Chunk, index: dict[int, np.ndarray]) -> None:
        """The wanted messages of one chunk, through its message indexes when it has them."""
        if index and self._known.issuperset(index) and not self._dest.keys() & index.keys():
            return  # nothing wanted in here: not even decompressed
        records, size = get_chunk_data_stream(chunk, validate_crc=True)  # CRC 0: none stored
        data = records.read(size)
        if not index or not self._known.issuperset(index):
            self._walk(data, 0, size, self._records)  # unindexed, or defines its channels
            return
        raw = np.frombuffer(data, np.uint8)
        for channel, entries in index.items():
            if channel not in self._dest:
                continue
            times, offsets = entries[:, 0].astype(np.int64), entries[:, 1].astype(np.int64)
            # rows of a sliding window: copied a row at a time, not byte by byte
            lengths = sliding_window_view(raw, 8)[offsets + 1].view('<u8')[:, 0]
            starts = offsets + _RECORD.size + _MESSAGE.size
            for length in np.unique(lengths):
                rows = np.flatnonzero(lengths == length)
                block = sliding_window_view(raw, int(length) - _MESSAGE.size)[starts[rows]]
                self._add(self._dest[channel], times[rows], self._records << 32 | offsets[rows],
                          block)

    def _add(self, topic: str, times: np.ndarray, keys: np.ndarray, block: np.ndarray) -> None:
        """Decode messages of one length (block (n, L) uint8) at once: only the decoded values
        are kept, not the bytes."""
        self.pieces[topic].append((times, keys, cdr.decode_block(self.layouts[topic], block)))


def _mcap_topics(files: list[Path], wanted: dict[str, str]) -> dict[str, tuple[np.ndarray,
                                                                             cdr.Decoded]]:
    """Log times and decoded messages of the ``wanted`` topics of MCAP files, in log-time order
    (file order on ties); ValueError when a message is not plain CDR."""
    reader = _McapTopics(wanted)
    for file in files:
        reader.read(file)
    out = {}
    for topic, msgtype in wanted.items():
        pieces = reader.pieces[topic]
        if not pieces:
            out[topic] = (np.zeros(0, np.int64), cdr.decode(LAYOUTS[msgtype], []))
            continue
        parts = [p[2] for p in pieces]
        times = np.concatenate([p[0] for p in pieces])
        sort = np.lexsort((np.concatenate([p[1] for p in pieces]), times))
        # in order already (one file, ordered chunks): a slice, no copies
        order = slice(None) if np.array_equal(sort, np.arange(sort.size)) else sort
        out[topic] = (times[order], cdr.Decoded(
            np.concatenate([p.stamps_ns for p in parts])[order],
            tuple(np.concatenate(col)[order] for col in zip(*(p.strings for p in parts),
                                                            strict=True)),
            np.concatenate([p.values for p in parts])[order]))
    return out


def _read_topics(reader: AnyReader, path: Path,
                 wanted: dict[str, str]) -> dict[str, TopicData]:
    """Decode every message of the ``wanted`` topics (topic -> message type with a fixed layout)
    in one pass over the bag, vectorised when the data are plain CDR (MCAP: ``_McapTopics``)."""
    conns = {topic: _topic_connections(reader, path, topic, msgtype)
             for topic, msgtype in wanted.items()}
    files = _mcap_files(path)
    if files is not None:
        try:
            fast = _mcap_topics(files, wanted)
        except Exception:  # whatever the fast path trips on, rosbags decides (and reports)
            pass
        else:
            return {topic: TopicData(times, dec.stamps_ns, dec.strings, dec.values)
                    for topic, (times, dec) in fast.items()}
    collected: dict[str, tuple[list[int], list[bytes]]] = {t: ([], []) for t in wanted}
    for conn, log_time, raw in reader.messages(connections=[c for cs in conns.values()
                                                            for c in cs]):
        times, raws = collected[conn.topic]
        times.append(log_time)
        raws.append(raw)
    return {topic: _decode_raws(reader, msgtype, *collected[topic])
            for topic, msgtype in wanted.items()}


def _decode_raws(reader: AnyReader, msgtype: str, times: list[int],
                 raws: list[bytes]) -> TopicData:
    """Messages of a fixed-layout type collected from rosbags as arrays: vectorised when they are
    plain CDR, else deserialised one by one with the bag's own definitions."""
    layout = LAYOUTS[msgtype]
    log_times = np.array(times, dtype=np.int64)
    try:
        dec = cdr.decode(layout, raws)
    except ValueError:
        dec, keep = _decode_each(reader, msgtype, raws)
        if keep.size < log_times.size:
            bad = np.setdiff1d(np.arange(log_times.size), keep)
            warnings.warn(InputWarning(
                f'{bad.size} malformed {msgtype} message(s) skipped (empty, truncated or a '
                f'string over {cdr.MAX_STRING} bytes; first at log time '
                f'{log_times[bad[0]] / 1e9:.6f} s)'), stacklevel=2)
        log_times = log_times[keep]
    return TopicData(log_times, dec.stamps_ns, dec.strings, dec.values)


def _decode_each(reader: AnyReader, msgtype: str,
                 raws: list[bytes]) -> tuple[cdr.Decoded, np.ndarray]:
    """Messages that are not all plain CDR: the well-formed plain ones vectorised, the others by
    rosbags with the bag's own definitions; those neither can read (0-byte, truncated) and
    those with a string over ``cdr.MAX_STRING`` are left out. Returns the decoded messages
    and their indices into ``raws`` (in order)."""
    layout = LAYOUTS[msgtype]
    plain = np.array([cdr.well_formed(layout, r) for r in raws], dtype=bool)
    keep, flat = list(np.flatnonzero(plain)), []
    longest = cdr.max_length(layout)
    for i in np.flatnonzero(~plain):
        if len(raws[i]) > longest:  # a string over cdr.MAX_STRING, whatever the encoding
            continue
        try:
            row = flatten(reader.deserialize(raws[i], msgtype), msgtype)
        except Exception:  # rosbags raises SerdeError, struct.error, ...
            continue
        if cdr.within_cap(row[1]):
            flat.append(row)
            keep.append(i)
    fast = cdr.decode(layout, [raws[i] for i in np.flatnonzero(plain)])
    stamps = np.concatenate([fast.stamps_ns, np.array([f[0] for f in flat], dtype=np.int64)])
    strings = tuple(np.concatenate([fast.strings[j], np.array([f[1][j] for f in flat],
                                                                dtype=str)])
                    for j in range(layout.n_strings))
    values = np.concatenate([fast.values,
                             np.array([f[2] for f in flat]).reshape(-1, layout.n_doubles)])
    order = np.argsort(keep, kind='stable')
    return (cdr.Decoded(stamps[order], tuple(s[order] for s in strings), values[order]),
            np.asarray(keep, dtype=np.int64)[order])


def read_stamped(path: str | Path, topic: str, msgtype: str) -> TopicData:
    """Every message of one topic whose type has a fixed layout (``messages.LAYOUTS``: Imu,
    Odometry, PointStamped, Vector3Stamped) as arrays, e.g. the truth of a simulated bag."""
    path = Path(path)
    if msgtype not in LAYOUTS:
        raise ValueError(f'no fixed layout for {msgtype}; use read_messages')
    with open_bag(path) as reader:
        return _read_topics(reader, path, {topic: msgtype})[topic]


@dataclass(frozen=True)
class ImuStream:
    """Accelerometer stream of a bag, in bag (log-time) order.

    stamps_ns (T,) int64: header.stamp (``stamp_source`` 'header'), or the log time when every
    header stamp is zero ('log_time'); accel (T, 3) m/s^2, NaN where REP 145 marks the field
    absent (linear_acceleration_covariance[0] = -1 or NaN); frame_ids (T,) str; covariance (T, 9)
    as recorded ((m/s^2)^2, row-major, zeros = unknown); odom_stamps_ns (M,) and speed_mps (M,)
    from Odometry twist.twist.linear.x (empty when the bag has no odometry topic);
    angular_velocity (T, 3) rad/s and gyro_covariance (T, 9) (rad/s)^2 as recorded (REP 145:
    gyro_covariance[:, 0] = -1 where the sensor has no gyro).
    """

    path: Path
    topic: str
    stamps_ns: np.ndarray
    log_time_ns: np.ndarray
    accel: np.ndarray
    frame_ids: np.ndarray
    covariance: np.ndarray
    odom_stamps_ns: np.ndarray
    speed_mps: np.ndarray
    stamp_source: str = 'header'
    gnss: GnssFixes | None = None  # NavSatFix messages of the same span (iter_imu), if asked
    angular_velocity: np.ndarray | None = None
    gyro_covariance: np.ndarray | None = None

    def accel_variance(self, default: float) -> np.ndarray:
        """Per-sample, per-axis variance (T, 3) in (m/s^2)^2: the recorded diagonal, ``default``
        where the covariance is all zeros (unknown), NaN where the field is absent."""
        diag = self.covariance[:, [0, 4, 8]].copy()
        unknown = ~np.any(self.covariance != 0, axis=1)
        diag[unknown] = default
        diag[np.isnan(self.accel[:, 0])] = np.nan
        return diag


def _stamps(data: TopicData) -> tuple[np.ndarray, str]:
    """Header stamps, or log times when the publisher left every header stamp at zero."""
    if data.stamps_ns.size and not np.any(data.stamps_ns):
        return data.log_time_ns, 'log_time'
    return data.stamps_ns, 'header'


def read_imu(path: str | Path, imu_topic: str = '/imu/data',
             odom_topic: str | None = '/odom') -> ImuStream:
    """Read the accelerometer stream (and odometry speeds, if present) of a bag."""
    path = Path(path)
    with open_bag(path) as reader:
        wanted = {imu_topic: IMU.msgtype}
        if odom_topic is not None and any(c.topic == odom_topic for c in reader.connections):
            wanted[odom_topic] = ODOMETRY.msgtype
        data = _read_topics(reader, path, wanted)
    imu = data[imu_topic]
    odom = data[odom_topic] if odom_topic is not None and odom_topic in data else None
    if imu.values.shape[0] == 0:
        raise InputError(f'{path}: topic {imu_topic} has no messages')
    stream = _imu_stream(path, imu_topic, imu, odom, _stamps(imu)[1],
                         _stamps(odom)[1] if odom is not None else 'header')
    if np.all(np.isnan(stream.accel[:, 0])):
        raise InputError(f'{path}: {imu_topic} carries no linear acceleration '
                         '(linear_acceleration_covariance[0] is -1 or NaN)')
    return stream


def _imu_stream(path: Path, imu_topic: str, imu: TopicData, odom: TopicData | None,
                imu_source: str, odom_source: str, gnss: GnssFixes | None = None) -> ImuStream:
    """An ImuStream of decoded Imu (and Odometry) messages; ``*_source``: 'header' or
    'log_time' (where the stamps come from)."""
    cov = imu.values[:, IMU_FIELDS['linear_acceleration_covariance']]
    absent = (cov[:, 0] == -1) | np.isnan(cov[:, 0])
    accel = imu.values[:, IMU_FIELDS['linear_acceleration']].copy()
    accel[absent] = np.nan
    stamps = imu.log_time_ns if imu_source == 'log_time' else imu.stamps_ns
    if odom is None:
        odom_stamps, speed = np.zeros(0, dtype=np.int64), np.zeros(0)
    else:
        odom_stamps = odom.log_time_ns if odom_source == 'log_time' else odom.stamps_ns
        speed = odom.values[:, ODOMETRY_FIELDS['twist.twist.linear'].start].copy()
    return ImuStream(path, imu_topic, stamps, imu.log_time_ns, accel, imu.strings[0], cov.copy(),
                     odom_stamps, speed, imu_source, gnss,
                     imu.values[:, IMU_FIELDS['angular_velocity']].copy(),
                     imu.values[:, IMU_FIELDS['angular_velocity_covariance']].copy())


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag: type, message count, first/last log time (ns)."""

    topic: str
    msgtype: str
    count: int
    start_ns: int
    end_ns: int


def summarize(path: str | Path) -> list[TopicSummary]:
    """Per-topic message counts and log-time spans (reads raw messages, decodes none)."""
    with open_bag(path) as reader:
        out = []
        for topic, info in sorted(reader.topics.items()):
            times = np.fromiter((t for _, t, _ in reader.messages(connections=info.connections)),
                                dtype=np.int64)
            if times.size == 0:
                out.append(TopicSummary(topic, info.msgtype or '?', 0, 0, 0))
            else:
                out.append(TopicSummary(topic, info.msgtype or '?', int(times.size),
                                        int(times.min()), int(times.max())))
    return out


# Chunked, time-ordered reading: railgsa invert and review go through a bag in bounded memory.

NAV_SAT_FIX = 'sensor_msgs/msg/NavSatFix'


@dataclass(frozen=True)
class GnssFixes:
    """NavSatFix messages: stamps_ns (N,) int64 (header, or log time when it is zero),
    latitude_deg, longitude_deg, altitude_m (N,) (WGS84), status (N,) int (NavSatStatus: -1 no
    fix, 0 fix, 1 SBAS, 2 GBAS), covariance (N, 9) m^2 (ENU, row-major) and its type (N,)."""

    stamps_ns: np.ndarray
    latitude_deg: np.ndarray
    longitude_deg: np.ndarray
    altitude_m: np.ndarray
    status: np.ndarray
    covariance: np.ndarray
    covariance_type: np.ndarray

    def __len__(self) -> int:
        return int(self.stamps_ns.size)

    @classmethod
    def concat(cls, parts: Sequence[GnssFixes]) -> GnssFixes:
        """Join fixes in order (an empty set for no parts)."""
        if not parts:
            return cls(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0),
                       np.zeros(0, np.int64), np.zeros((0, 9)), np.zeros(0, np.int64))
        return cls(**{f: np.concatenate([getattr(p, f) for p in parts])
                      for f in cls.__dataclass_fields__})


def _gnss_fixes(times: np.ndarray, raws: Sequence[bytes]) -> GnssFixes:
    """NavSatFix messages deserialised one by one with rosbags (a few per second: no vectorised
    layout needed); a zero header stamp takes the log time."""
    store = typestore()
    msgs = [store.deserialize_cdr(bytes(r), NAV_SAT_FIX) for r in raws]
    stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                       for m in msgs], dtype=np.int64)
    stamps = np.where(stamps == 0, np.asarray(times, np.int64), stamps)
    latitude, longitude, altitude = (np.array([getattr(m, f) for m in msgs], dtype=float)
                                     for f in ('latitude', 'longitude', 'altitude'))
    return GnssFixes(stamps, latitude, longitude, altitude,
                     np.array([m.status.status for m in msgs], dtype=np.int64),
                     np.array([m.position_covariance for m in msgs],
                              dtype=float).reshape(-1, 9),
                     np.array([m.position_covariance_type for m in msgs], dtype=np.int64))


class _McapChunks(_McapTopics):
    """``_McapTopics`` handing its messages out chunk by chunk in log-time order (file order on
    ties). After each MCAP chunk, the messages older than every chunk still to come (their
    ``message_start_time`` from the files' chunk indexes) are complete and go out; a file
    without a summary (a recording cut short) is taken in chunk order. Memory is bounded when
    the chunks follow each other in log time, as recorders write them; where later chunks hold
    earlier messages (a topic written after the others), the messages wait until those chunks
    are read. Topics of a type
    without a fixed layout (NavSatFix) keep their messages' bytes."""

    def __init__(self, wanted: dict[str, str]) -> None:
        super().__init__({t: m for t, m in wanted.items() if m in LAYOUTS})
        self.raw: dict[str, list[tuple[np.ndarray, np.ndarray, list[bytes]]]] = {
            t: [] for t, m in wanted.items() if m not in LAYOUTS}  # kept as bytes
        self.wanted.update(self.raw)

    def _add(self, topic: str, times: np.ndarray, keys: np.ndarray, block: np.ndarray) -> None:
        if topic in self.raw:
            self.raw[topic].append((times, keys, [row.tobytes() for row in block]))
        else:
            super()._add(topic, times, keys, block)

    def stream(self, files: list[Path]) -> Iterator[tuple[float, Batch]]:
        """Per MCAP chunk: (boundary, batch) where batch maps topic -> (log times, cdr.Decoded or
        list of bytes) of the messages logged before ``boundary`` (ns) not given before, in
        log-time order."""
        starts = [_chunk_starts(f) for f in files]
        later = np.minimum.accumulate(
            np.concatenate([s if s is not None else [] for s in starts] + [[np.inf]])[::-1])[::-1]
        done = 0
        for file, file_starts in zip(files, starts, strict=True):
            for _ in self.chunks(file):
                if file_starts is None:
                    yield np.inf, self._take(np.inf)
                    continue
                done = min(done + 1, later.size - 1)
                yield later[done], self._take(later[done])
        yield np.inf, self._take(np.inf)

    def _take(self, boundary: float) -> Batch:
        """Remove and return the messages logged before ``boundary`` (ns), sorted."""
        out: Batch = {}
        for topic, pieces in self.pieces.items():
            if not pieces:
                out[topic] = (np.zeros(0, np.int64), cdr.decode(self.layouts[topic], []))
                continue
            times, keys, now, rest = _cut(pieces, boundary)
            parts = [p[2] for p in pieces]
            dec = cdr.Decoded(np.concatenate([p.stamps_ns for p in parts]),
                              tuple(np.concatenate(c) for c in
                                    zip(*(p.strings for p in parts), strict=True)),
                              np.concatenate([p.values for p in parts]))
            out[topic] = (times[now], _rows(dec, now))
            self.pieces[topic] = [(times[rest], keys[rest], _rows(dec, rest))] if rest.size else []
        for topic, raw_pieces in self.raw.items():
            if not raw_pieces:
                out[topic] = (np.zeros(0, np.int64), [])
                continue
            times, keys, now, rest = _cut(raw_pieces, boundary)
            raws = [r for p in raw_pieces for r in p[2]]
            out[topic] = (times[now], [raws[i] for i in now])
            self.raw[topic] = ([(times[rest], keys[rest], [raws[i] for i in rest])]
                               if rest.size else [])
        return out


def _cut(pieces: Sequence[tuple[np.ndarray, np.ndarray, object]], boundary: float
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(log times, keys, rows logged before ``boundary`` (ns), the other rows) of a topic's
    pieces, both row lists in (log time, key) order."""
    times = np.concatenate([p[0] for p in pieces])
    keys = np.concatenate([p[1] for p in pieces])
    order = np.lexsort((keys, times))
    cut = int(np.searchsorted(times[order], boundary, side='left'))
    return times, keys, order[:cut], order[cut:]


def _rows(dec: cdr.Decoded, rows: np.ndarray) -> cdr.Decoded:
    """The messages ``rows`` of a Decoded."""
    return cdr.Decoded(dec.stamps_ns[rows], tuple(s[rows] for s in dec.strings), dec.values[rows])


def _chunk_starts(file: Path) -> np.ndarray | None:
    """``message_start_time`` (ns) of an MCAP file's chunks in file order (its summary's chunk
    indexes), None without a summary."""
    from mcap.reader import make_reader

    with file.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    if summary is None or not summary.chunk_indexes:
        return None
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    return np.array([c.message_start_time for c in indexes], dtype=float)


def _rosbags_stream(reader: AnyReader, conns: list[Connection], wanted: dict[str, str],
                    chunk: int, after: float = -np.inf) -> Iterator[Batch]:
    """rosbags' log-time ordered messages of ``wanted`` logged at or after ``after`` (ns) in
    batches of about ``chunk`` messages: topic -> (log times, raw messages)."""
    batch: dict[str, tuple[list[int], list[bytes]]] = {t: ([], []) for t in wanted}
    count = 0
    for conn, log_time, raw in reader.messages(connections=conns):
        if log_time < after:
            continue
        times, raws = batch[conn.topic]
        times.append(log_time)
        raws.append(raw)
        count += 1
        if count >= chunk:
            yield {t: (np.array(ts, np.int64), rs) for t, (ts, rs) in batch.items()}
            batch, count = {t: ([], []) for t in wanted}, 0
    yield {t: (np.array(ts, np.int64), rs) for t, (ts, rs) in batch.items()}


def iter_imu(path: str | Path, imu_topic: str = '/imu/data', odom_topic: str | None = '/odom',
             gnss_topic: str | None = None, chunk: int = CHUNK) -> Iterator[ImuStream]:
    """The accelerometer stream of a bag (with its odometry, and NavSatFix fixes of
    ``gnss_topic`` when it is in the bag) as ImuStream pieces of about ``chunk`` IMU samples, in
    log-time order: memory bounded by the chunk, not by the run. Every message of a piece is
    logged before every message of the next one. Stamps: header stamps, or the log times when
    every header stamp of the first piece with messages is zero (decided once per topic). The
    MCAP fast path (``_McapChunks``) is taken when it can read the bag, rosbags otherwise.
    InputError as ``read_imu`` (checked over the whole run: raised at the end)."""
    path = Path(path)
    with open_bag(path) as reader:
        topics = {c.topic for c in reader.connections}
        wanted = {imu_topic: IMU.msgtype}
        conns = _topic_connections(reader, path, imu_topic, IMU.msgtype)
        for topic, msgtype in ((odom_topic, ODOMETRY.msgtype), (gnss_topic, NAV_SAT_FIX)):
            if topic is not None and topic in topics:
                wanted[topic] = msgtype
                conns += _topic_connections(reader, path, topic, msgtype)
        batches = _batches(path, reader, conns, wanted, chunk)
        yield from _imu_pieces(path, reader, wanted, imu_topic, odom_topic, gnss_topic, batches,
                               chunk)


def iter_topics(path: str | Path, wanted: dict[str, str], chunk: int = CHUNK
                ) -> Iterator[dict[str, TopicData | GnssFixes]]:
    """Batches of the ``wanted`` topics (topic -> Imu, Odometry, PointStamped, Vector3Stamped or
    NavSatFix type; absent topics are skipped) in log-time order, decoded: topic -> TopicData
    (GnssFixes for NavSatFix). Same paths and errors as ``iter_imu``."""
    path = Path(path)
    with open_bag(path) as reader:
        topics = {c.topic for c in reader.connections}
        wanted = {t: m for t, m in wanted.items() if t in topics}
        conns = [c for t, m in wanted.items() for c in _topic_connections(reader, path, t, m)]
        if not wanted:
            return
        for batch in _batches(path, reader, conns, wanted, chunk):
            yield {t: _decode_batch(reader, wanted[t], times, body)
                   for t, (times, body) in batch.items() if len(times)}


def _decode_batch(reader: AnyReader, msgtype: str, times: np.ndarray,
                  body: Body) -> TopicData | GnssFixes:
    """Messages of one topic of a batch (cdr.Decoded of the fast path, or raw bytes: always
    for NavSatFix, which has no fixed layout)."""
    if isinstance(body, cdr.Decoded):
        return TopicData(times, body.stamps_ns, body.strings, body.values)
    if msgtype == NAV_SAT_FIX:
        return _gnss_fixes(times, body)
    return _decode_raws(reader, msgtype, list(times), body)


def _batches(path: Path, reader: AnyReader, conns: list[Connection], wanted: dict[str, str],
             chunk: int) -> Iterator[Batch]:
    """Batches of the MCAP fast path; if it trips (a message that is not plain CDR, ...),
    rosbags goes on from the first message not given yet."""
    given = -np.inf  # every message logged before this was given
    files = _mcap_files(path)
    if files is not None:
        try:
            for boundary, batch in _McapChunks(wanted).stream(files):
                yield batch
                given = boundary
            return
        except Exception as exc:  # rosbags decides (and reports)
            if given == np.inf:
                raise InputError(f'{path}: unreadable bag ({_one_line(exc)})') from None
    yield from _rosbags_stream(reader, conns, wanted, chunk, given)


def _imu_pieces(path: Path, reader: AnyReader, wanted: dict[str, str], imu_topic: str,
                odom_topic: str | None, gnss_topic: str | None,
                batches: Iterator[Batch], chunk: int) -> Iterator[ImuStream]:
    """Decoded batches regrouped into ImuStream pieces of at least ``chunk`` IMU samples (the
    last one smaller)."""
    sources: dict[str, str] = {}
    held: dict[str, list[TopicData]] = {t: [] for t, m in wanted.items() if m != NAV_SAT_FIX}
    fixes: list[GnssFixes] = []  # of gnss_topic
    count = messages = accelerations = 0

    def hold(topic: str, times: np.ndarray, body: Body) -> None:
        data = _decode_batch(reader, wanted[topic], times, body)
        if isinstance(data, GnssFixes):
            fixes.append(data)
            return
        if topic not in sources and data.stamps_ns.size:
            sources[topic] = _stamps(data)[1]
        held[topic].append(data)

    def piece() -> ImuStream:
        imu = _concat_topic(held[imu_topic], LAYOUTS[wanted[imu_topic]])
        odom, odom_source = None, 'header'
        if odom_topic is not None and odom_topic in held:
            odom = _concat_topic(held[odom_topic], LAYOUTS[wanted[odom_topic]])
            odom_source = sources.get(odom_topic, 'header')
        gnss = GnssFixes.concat(fixes) if gnss_topic in wanted else None
        for parts in held.values():
            parts.clear()
        fixes.clear()
        return _imu_stream(path, imu_topic, imu, odom, sources.get(imu_topic, 'header'),
                           odom_source, gnss)

    for batch in batches:
        for topic, (times, body) in batch.items():
            if len(times):
                hold(topic, times, body)
        count = sum(len(p.stamps_ns) for p in held[imu_topic])
        if count >= chunk:
            out = piece()
            messages += len(out.stamps_ns)
            accelerations += _present(out)
            yield out
    out = piece()
    messages += len(out.stamps_ns)
    accelerations += _present(out)
    if messages == 0:
        raise InputError(f'{path}: topic {imu_topic} has no messages')
    if accelerations == 0:
        raise InputError(f'{path}: {imu_topic} carries no linear acceleration '
                         '(linear_acceleration_covariance[0] is -1 or NaN)')
    if len(out.stamps_ns) or (out.gnss is not None and len(out.gnss)) or out.speed_mps.size:
        yield out


def _present(stream: ImuStream) -> int:
    """Messages that carry a linear acceleration (REP 145: covariance[0] not -1 or NaN)."""
    first = stream.covariance[:, 0]
    return int(np.sum((first != -1) & ~np.isnan(first)))


def _concat_topic(parts: list[TopicData], layout: cdr.StampedLayout) -> TopicData:
    """Pieces of one fixed-layout topic joined (empty arrays for none)."""
    if not parts:
        empty = cdr.decode(layout, [])
        return TopicData(np.zeros(0, np.int64), empty.stamps_ns, empty.strings, empty.values)
    return TopicData(np.concatenate([p.log_time_ns for p in parts]),
                     np.concatenate([p.stamps_ns for p in parts]),
                     tuple(np.concatenate(c) for c in zip(*(p.strings for p in parts),
                                                          strict=True)),
                     np.concatenate([p.values for p in parts]))
