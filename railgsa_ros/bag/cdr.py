"""Vectorised CDR (XCDR1) coding of stamped messages with a fixed float64 body.

Many standard messages (Imu, PointStamped, Vector3Stamped, Odometry) serialise as a
``std_msgs/Header`` (int32 sec, uint32 nanosec, string frame_id), optional further strings, then a
block of float64 aligned to 8 bytes. Coding a whole stream of them is then a few numpy slices
instead of one Python object per message (rosbags needs ~12-22 us per message). Anything else
(other encapsulations such as XCDR2, truncated data) raises ValueError so that callers fall back to
the general deserialiser.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
import struct
from typing import Literal, overload

import numpy as np

_CDR_LE = b'\x00\x01\x00\x00'
_NS = 1_000_000_000
#: longest string (bytes with its NUL) a message may carry: frame ids are a few dozen bytes; a
#: longer one is malformed (a 50,000-character frame_id made every row of a numpy string column
#: 200 kB wide: 6 GB for one bag)
MAX_STRING = 256
#: ``decode`` reads at most this many messages one by one (struct, ~3 us each) instead of
#: vectorised (~20-40 us of numpy calls however few): a node decodes batches of 1-2 messages
FEW = 4


@dataclass(frozen=True)
class StampedLayout:
    """CDR layout: header + ``n_strings - 1`` more strings + ``n_doubles`` float64 values."""

    msgtype: str
    n_strings: int
    n_doubles: int


@dataclass(frozen=True)
class Decoded:
    """Decoded stream: stamps_ns (N,) int64, strings[j] (N,) str arrays, values (N, n_doubles);
    ``nanosec`` (N,) int64: header.stamp.nanosec as sent (a value >= 1e9 is invalid but folds
    into stamps_ns unnoticed), None where not kept."""

    stamps_ns: np.ndarray
    strings: tuple[np.ndarray, ...]
    values: np.ndarray
    nanosec: np.ndarray | None = None


#: (stamp_ns, nanosec, strings, float64 body) of one message, for what ``decode`` cannot read
Fallback = Callable[[bytes], tuple[int, int, tuple[str, ...], np.ndarray]]


@overload
def _align(offset: int, size: int) -> int: ...


@overload
def _align(offset: np.ndarray, size: int) -> np.ndarray: ...


def _align(offset: np.ndarray | int, size: int) -> np.ndarray | int:
    """Round an offset (one, or one per message) up to a multiple of ``size`` bytes."""
    return (offset + size - 1) // size * size


def within_cap(strings: Sequence[str]) -> bool:
    """Whether every string, UTF-8 with its NUL, fits MAX_STRING bytes (for what another
    deserialiser read)."""
    return all(len(text.encode('utf-8')) < MAX_STRING for text in strings)


def max_length(layout: StampedLayout) -> int:
    """Bytes of the longest message of ``layout`` whose strings are within MAX_STRING (the
    strings' alignment and the body's included): a longer one has a string over the cap."""
    return 4 + 8 + layout.n_strings * (3 + 4 + MAX_STRING) + 7 + 8 * layout.n_doubles


def split_stamps(stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """int64 ns -> (sec int32, nanosec uint32) as in builtin_interfaces/Time; ValueError if out of
    the int32 range of seconds."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    sec, nsec = np.divmod(stamps_ns, _NS)
    if stamps_ns.size and (sec.min() < -2**31 or sec.max() >= 2**31):
        raise ValueError('stamp outside the int32 seconds range of builtin_interfaces/Time')
    return sec.astype(np.int32), nsec.astype(np.uint32)


def encode(layout: StampedLayout, stamps_ns: np.ndarray, strings: Sequence[str],
           values: np.ndarray) -> list[bytes]:
    """Serialise N messages (little-endian CDR) with the same strings; values shape (N, n_doubles)
    or (n_doubles,) broadcast to every message."""
    rows = encode_rows(layout, stamps_ns, strings, values)
    flat, size = rows.tobytes(), rows.shape[1]
    return [flat[i:i + size] for i in range(0, rows.size, size)] if rows.size else []


def encode_rows(layout: StampedLayout, stamps_ns: np.ndarray, strings: Sequence[str],
                values: np.ndarray) -> np.ndarray:
    """``encode`` as one (N, L) uint8 array: message i is row i (all the same length), what
    ``BagWriter.write_batches`` writes without a Python object per message."""
    if len(strings) != layout.n_strings:
        raise ValueError(f'{layout.msgtype}: expected {layout.n_strings} strings')
    sec, nsec = split_stamps(stamps_ns)
    n = sec.size
    if n == 0:
        return np.zeros((0, 0), np.uint8)
    values = np.broadcast_to(np.asarray(values, dtype='<f8'), (n, layout.n_doubles))
    prefix = bytearray()
    for text in strings:
        data = text.encode('utf-8') + b'\x00'
        prefix += b'\x00' * (_align(8 + len(prefix), 4) - 8 - len(prefix))
        prefix += np.uint32(len(data)).astype('<u4').tobytes() + data
    body_at = _align(8 + len(prefix), 8)
    prefix += b'\x00' * (body_at - 8 - len(prefix))
    size = 4 + body_at + 8 * layout.n_doubles
    buf = np.empty((n, size), dtype=np.uint8)
    buf[:, :4] = np.frombuffer(_CDR_LE, np.uint8)
    buf[:, 4:8] = sec.astype('<i4').view(np.uint8).reshape(n, 4)
    buf[:, 8:12] = nsec.astype('<u4').view(np.uint8).reshape(n, 4)
    buf[:, 12:4 + body_at] = np.frombuffer(bytes(prefix), np.uint8)
    buf[:, 4 + body_at:] = np.ascontiguousarray(values).view(np.uint8).reshape(n, -1)
    return buf


def _read_u32(block: np.ndarray, cols: np.ndarray, little: np.ndarray) -> np.ndarray:
    """Per-row uint32 at byte column ``cols`` (N,) of ``block`` (N, L), per-row endianness."""
    rows = np.arange(block.shape[0])
    b = block[rows[:, None], cols[:, None] + np.arange(4)].astype(np.uint64)
    le = b[:, 0] | b[:, 1] << 8 | b[:, 2] << 16 | b[:, 3] << 24
    be = b[:, 3] | b[:, 2] << 8 | b[:, 1] << 16 | b[:, 0] << 24
    return np.where(little, le, be).astype(np.int64)


def _unique_rows(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """np.unique(rows, axis=0, return_inverse=True), fast when every row is the same."""
    if rows.shape[0] == 0 or np.all(rows == rows[0]):
        return rows[:1], np.zeros(rows.shape[0], dtype=np.int64)
    uniq, inverse = np.unique(rows, axis=0, return_inverse=True)
    return uniq, inverse.ravel()


def well_formed(layout: StampedLayout, data: bytes) -> bool:
    """Whether one message has the structure ``decode_block`` needs (XCDR1 encapsulation, every
    string in bounds, at most MAX_STRING bytes and NUL-terminated, the float64 body complete):
    a cheap per-message check
    (about 1 us) for the replay, which forwards bytes without decoding them."""
    if len(data) < 16 or data[0] != 0 or data[1] > 1:
        return False
    end = '<' if data[1] == 1 else '>'
    offset = 8
    for _ in range(layout.n_strings):
        offset = _align(offset, 4)
        if 4 + offset + 4 > len(data):
            return False
        count = int.from_bytes(data[4 + offset:8 + offset], 'little' if end == '<' else 'big')
        if not 1 <= count <= MAX_STRING or 8 + offset + count > len(data) or \
                data[7 + offset + count] != 0:
            return False
        offset += 4 + count
    return _align(offset, 8) + 4 + 8 * layout.n_doubles <= len(data)


def decode_block(layout: StampedLayout, block: np.ndarray) -> Decoded:
    """Decode messages of one byte length: ``block`` is (N, L) uint8."""
    n, length = block.shape
    if length < 16 or np.any(block[:, 0] != 0) or np.any(block[:, 1] > 1):
        raise ValueError('not plain CDR (XCDR1) data')
    if length > max_length(layout):
        raise ValueError(f'a string longer than {MAX_STRING} bytes')
    uniform = _decode_uniform(layout, block)
    if uniform is not None:
        return uniform
    little = block[:, 1] == 1
    offset = np.full(n, 8, dtype=np.int64)
    str_pos, str_len = [], []
    for _ in range(layout.n_strings):
        offset = _align(offset, 4)
        if np.any(4 + offset + 4 > length):
            raise ValueError('truncated message')
        count = _read_u32(block, 4 + offset, little)
        str_pos.append(4 + offset + 4)
        str_len.append(count)
        offset = offset + 4 + count
    offset = _align(offset, 8)
    if np.any(offset + 4 + 8 * layout.n_doubles > length) or any(np.any(c < 1) for c in str_len):
        raise ValueError('truncated message')
    if any(np.any(c > MAX_STRING) for c in str_len):
        raise ValueError(f'a string longer than {MAX_STRING} bytes')
    key = np.stack([little.astype(np.int64), offset, *str_len], axis=1)
    groups, inverse = _unique_rows(key)
    pieces = []
    for g, (is_le, body, *lengths) in enumerate(groups):
        rows = np.flatnonzero(inverse == g) if len(groups) > 1 else slice(None)
        sub = block[rows]
        end = '<' if is_le else '>'
        sec = sub[:, 4:8].copy().view(end + 'i4')[:, 0].astype(np.int64)
        nsec = sub[:, 8:12].copy().view(end + 'u4')[:, 0].astype(np.int64)
        start = 4 + body
        values = sub[:, start:start + 8 * layout.n_doubles].copy().view(end + 'f8')
        strings = []
        for j, count in enumerate(lengths):
            pos = int(str_pos[j][0 if isinstance(rows, slice) else rows[0]])
            uniq, inv = _unique_rows(sub[:, pos:pos + count - 1])
            strings.append(np.array([bytes(u).decode('utf-8', 'replace') for u in uniq])[inv])
        pieces.append((rows, Decoded(sec * _NS + nsec, tuple(strings), values, nsec)))
    return _combine(pieces, n, layout)


def _decode_uniform(layout: StampedLayout, block: np.ndarray) -> Decoded | None:
    """``decode_block`` when every message is laid out as the first (one endianness, the same
    string lengths: one publisher's stream), in a few numpy calls (a node decodes batches of a
    few messages, where the general path's fixed cost dominates); None otherwise."""
    n, length = block.shape
    first = block[0].tobytes()
    order: Literal['little', 'big'] = 'little' if first[1] == 1 else 'big'
    offset, spans = 8, []
    for _ in range(layout.n_strings):
        offset = _align(offset, 4)
        if 4 + offset + 4 > length:
            return None
        count = int.from_bytes(first[4 + offset:8 + offset], order)
        if not 1 <= count <= MAX_STRING:
            return None
        spans.append((4 + offset, 8 + offset + count))  # length field .. NUL
        offset += 4 + count
    body = 4 + _align(offset, 8)
    if body + 8 * layout.n_doubles > length:
        return None
    strings = []
    for start, stop in spans:
        column = block[:, start:stop]
        if n > 1 and not (column == column[0]).all():
            return None
        strings.append(np.full(n, first[start + 4:stop - 1].decode('utf-8', 'replace')))
    if n > 1 and not (block[:, 1] == block[0, 1]).all():
        return None
    end = '<' if order == 'little' else '>'
    head = block[:, 4:12].copy().view(end + 'u4')
    sec, nsec = head[:, 0].view(end + 'i4').astype(np.int64), head[:, 1].astype(np.int64)
    values = block[:, body:body + 8 * layout.n_doubles].copy().view(end + 'f8')
    return Decoded(sec * _NS + nsec, tuple(strings), values, nsec)


def _combine(pieces: Sequence[tuple[np.ndarray | slice, Decoded]], n: int,
             layout: StampedLayout) -> Decoded:
    """Scatter decoded parts (row indices, part) into one Decoded of n rows."""
    if len(pieces) == 1 and isinstance(pieces[0][0], slice):
        return pieces[0][1]
    stamps, nanosec = np.empty(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
    values = np.empty((n, layout.n_doubles))
    strings = [np.empty(n, dtype=np.result_type(*(p.strings[j] for _, p in pieces)))
               for j in range(layout.n_strings)]
    for rows, part in pieces:
        stamps[rows] = part.stamps_ns
        if part.nanosec is not None:  # always, for parts of decode_block
            nanosec[rows] = part.nanosec
        values[rows] = part.values
        for j, text in enumerate(part.strings):
            strings[j][rows] = text
    return Decoded(stamps, tuple(strings), values, nanosec)


def _decode_one(layout: StampedLayout, data: bytes) -> tuple[int, int, list[str], tuple]:
    """(sec, nanosec, strings, body) of one message, with ``decode_block``'s checks and
    results; ValueError where it raises."""
    if len(data) < 16 or data[0] != 0 or data[1] > 1:
        raise ValueError('not plain CDR (XCDR1) data')
    end = '<' if data[1] == 1 else '>'
    sec, nsec = struct.unpack_from(end + 'iI', data, 4)
    offset, strings = 8, []
    for _ in range(layout.n_strings):
        offset = _align(offset, 4)
        if 4 + offset + 4 > len(data):
            raise ValueError('truncated message')
        count = struct.unpack_from(end + 'I', data, 4 + offset)[0]
        if count < 1:
            raise ValueError('truncated message')
        if count > MAX_STRING:
            raise ValueError(f'a string longer than {MAX_STRING} bytes')
        strings.append(data[8 + offset:7 + offset + count].decode('utf-8', 'replace'))
        offset += 4 + count
    body = 4 + _align(offset, 8)
    if body + 8 * layout.n_doubles > len(data):
        raise ValueError('truncated message')
    return sec, nsec, strings, struct.unpack_from(f'{end}{layout.n_doubles}d', data, body)


def _decode_few(layout: StampedLayout, raws: Sequence[bytes | memoryview]) -> Decoded:
    """``decode`` one message at a time: the same values for up to ``FEW`` messages."""
    rows = [_decode_one(layout, bytes(raw)) for raw in raws]
    nsec = np.array([r[1] for r in rows], np.int64)
    return Decoded(np.array([r[0] for r in rows], np.int64) * _NS + nsec,
                   tuple(np.array([r[2][j] for r in rows]) for j in range(layout.n_strings)),
                   np.array([r[3] for r in rows], float).reshape(len(rows), layout.n_doubles),
                   nsec)


def decode(layout: StampedLayout, raws: Sequence[bytes | memoryview]) -> Decoded:
    """Decode N serialised messages of ``layout``; ValueError if any is not plain CDR or has a
    string over MAX_STRING."""
    if not raws:
        empty = tuple(np.zeros(0, dtype=str) for _ in range(layout.n_strings))
        return Decoded(np.zeros(0, dtype=np.int64), empty, np.zeros((0, layout.n_doubles)),
                       np.zeros(0, dtype=np.int64))
    if len(raws) <= FEW:
        return _decode_few(layout, raws)
    lengths = np.fromiter(map(len, raws), dtype=np.int64, count=len(raws))
    if lengths.max() > max_length(layout):
        raise ValueError(f'a string longer than {MAX_STRING} bytes')
    if np.all(lengths == lengths[0]):
        block = np.frombuffer(b''.join(raws), np.uint8)
        return decode_block(layout, block.reshape(len(raws), int(lengths[0])))
    pieces = []
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        block = np.frombuffer(b''.join([raws[i] for i in rows.tolist()]), np.uint8)
        pieces.append((rows, decode_block(layout, block.reshape(rows.size, int(length)))))
    return _combine(pieces, len(raws), layout)


def _unreadable(raw: bytes) -> tuple[int, int, tuple[str, ...], np.ndarray]:
    raise ValueError('not plain CDR and no fallback')


def decode_valid(layout: StampedLayout, raws: Sequence[bytes],
                 fallback: Fallback | None = None) -> tuple[Decoded, np.ndarray]:
    """Decode what can be read of N messages, never raising: the plain CDR ones vectorised,
    the others through ``fallback`` (e.g. a general deserialiser for other encodings); those
    neither reads (truncated, garbage) and those with a string over MAX_STRING are left out.
    Returns the decoded messages and their indices into ``raws`` (increasing)."""
    try:
        return decode(layout, raws), np.arange(len(raws))
    except ValueError:
        pass
    plain = np.fromiter((well_formed(layout, r) for r in raws), dtype=bool, count=len(raws))
    fast = decode(layout, [raws[i] for i in np.flatnonzero(plain).tolist()])
    read = fallback if fallback is not None else _unreadable
    rows = []
    longest = max_length(layout)
    for i in np.flatnonzero(~plain).tolist():
        if len(raws[i]) > longest:  # a string over the cap, whatever the encoding
            continue
        try:
            row = read(raws[i])
        except Exception:  # whatever a deserialiser raises on bad bytes
            continue
        if within_cap(row[2]):
            rows.append((i, *row))
    if not rows:
        return fast, np.flatnonzero(plain)
    keep = np.concatenate([np.flatnonzero(plain), [r[0] for r in rows]]).astype(np.int64)
    order = np.argsort(keep, kind='stable')
    stamps = np.concatenate([fast.stamps_ns, np.array([r[1] for r in rows], np.int64)])
    nanosec = np.concatenate([fast.nanosec, np.array([r[2] for r in rows], np.int64)])
    strings = tuple(np.concatenate([fast.strings[j], np.array([r[3][j] for r in rows], str)])
                    for j in range(layout.n_strings))
    values = np.concatenate([fast.values, np.array([r[4] for r in rows], float).reshape(
        -1, layout.n_doubles)])
    return (Decoded(stamps[order], tuple(t[order] for t in strings), values[order],
                    nanosec[order]), keep[order])
