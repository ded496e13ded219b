"""``railgsa recover``: make a bag readable again after its recorder was killed.

A recorder killed with SIGKILL (or a power cut) leaves the file in progress without the MCAP
summary and footer, and ``metadata.yaml`` does not list it (or does not exist yet): no reader
opens it. ``railgsa record`` closes and fsyncs a chunk every second, so the file holds every
message up to about its last second. ``recover_bag`` walks each unfinished file record by
record, keeps every complete record (chunks only when their CRC, where stored, matches and they
decompress), stops at the cut, rewrites the file as a complete MCAP (the original is kept as
``NAME.mcap.orig``) and writes ``metadata.yaml`` for all the bag's files. Finished files are
left as they are. The recorder's ``*.mcap.partial`` files (a write error) are recovered too.
A file with nothing to keep (0 bytes, no complete message) or that cannot be read (not MCAP,
a damaged summary, an I/O error) is set aside as ``NAME.mcap.orig`` and left out of
``metadata.yaml``: the rest of the recording is kept.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
import os
from pathlib import Path
import re
import struct
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import CRCValidationError, get_chunk_data_stream
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer
import yaml
from zstandard import ZstdError

from railgsa_ros.bag.reader import mcap_finished
from railgsa_ros.errors import InputError
from railgsa_ros.playback.recording import CHUNK_BYTES, Segment, topic_entry, write_metadata

_RECORD = struct.Struct('<BQ')  # MCAP record: opcode, content length
_ORIGINAL = '.orig'
#: what a damaged chunk raises: CRC mismatch, corrupt zstd/lz4 data, a record cut inside it
_DAMAGED = (McapError, CRCValidationError, ZstdError, ValueError, RuntimeError, EOFError,
            struct.error)


@dataclass
class FileReport:
    """What recovery did with one storage file: ``status`` is finished (left alone),
    recovered (rewritten from its complete records), empty (no complete message: set aside)
    or unreadable (set aside, ``reason`` says why); messages kept, complete chunks dropped for
    a CRC or decompression failure, bytes after the cut."""

    name: str
    status: str
    messages: int
    bad_chunks: int = 0
    cut_bytes: int = 0
    reason: str = ''


@dataclass
class _Salvage:
    """The complete records of an unfinished MCAP file."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    compression: str = ''
    bad_chunks: int = 0
    cut_bytes: int = 0


def recover_bag(path: str | Path) -> list[FileReport]:
    """Recover the MCAP bag directory (or bare .mcap file) ``path`` in place; InputError naming
    it when it is neither. Returns one report per storage file, in file order."""
    path = Path(path)
    if path.is_file() and path.suffix == '.mcap':  # a bare file: rewritten, no metadata.yaml
        report = _recover_file(path)
        if report.status == 'empty':
            raise InputError(f'{path}: no complete message: nothing to recover')
        return [report]
    if not path.is_dir():
        raise InputError(f'{path}: not a bag directory or .mcap file')
    candidates = sorted([*path.glob('*.mcap'), *path.glob('*.mcap.partial')], key=_file_order)
    if not candidates:
        raise InputError(f'{path}: no .mcap file to recover')
    reports, segments = [], []
    topics: dict[str, tuple[str, list, str, int]] = {}  # name -> type, QoS, type hash, count
    for file in candidates:
        try:
            report = _recover_file(file)
            if report.status != 'empty':
                segments.append(_segment(path / report.name, topics))
        except (InputError, OSError, *_DAMAGED) as exc:
            reason = str(exc).removeprefix(f'{file}: ') if isinstance(exc, InputError) \
                else ' '.join(str(exc).split())[:120] or type(exc).__name__
            report = FileReport(file.name.removesuffix('.partial'), 'unreadable', 0,
                                reason=reason)
        if report.status in ('empty', 'unreadable'):
            _set_aside(file)
        reports.append(report)
    if not segments:
        raise InputError(f'{path}: no readable message in any file ('
                         + '; '.join(f'{r.name}: {r.status}' for r in reports) + ')')
    write_metadata(path, segments, [
        topic_entry(name, msgtype, qos, type_hash, count)
        for name, (msgtype, qos, type_hash, count) in topics.items()])
    return reports


def _set_aside(file: Path) -> None:
    """Rename a file with nothing readable ``NAME.mcap.orig``: readers refuse a bag holding an
    unfinished .mcap, and the original is kept for whoever wants to look at it."""
    if file.exists():
        file.rename(file.with_name(file.name.removesuffix('.partial') + _ORIGINAL))


def _file_order(file: Path) -> tuple[int, str]:
    """Sort key: the recorder's split index (``OUT_12.mcap`` after ``OUT_2.mcap``), then name."""
    match = re.search(r'_(\d+)\.mcap', file.name)
    return (int(match.group(1)) if match else -1, file.name)


def _recover_file(file: Path) -> FileReport:
    """Rewrite one unfinished file (``.partial`` becomes ``.mcap``); finished ones stay."""
    name = file.name.removesuffix('.partial')
    if file.suffix == '.mcap' and mcap_finished(file):
        return FileReport(name, 'finished', _message_count(file))
    if file.stat().st_size == 0:
        return FileReport(name, 'empty', 0)
    salvage = _salvage(file)
    if not salvage.messages:
        return FileReport(name, 'empty', 0, salvage.bad_chunks, salvage.cut_bytes)
    tmp = file.with_name(name + '.tmp')
    with tmp.open('wb') as out:
        _write(out, salvage)
        out.flush()
        os.fsync(out.fileno())
    file.rename(file.with_name(name + _ORIGINAL))
    tmp.replace(file.with_name(name))
    return FileReport(name, 'recovered', len(salvage.messages), salvage.bad_chunks,
                      salvage.cut_bytes)


def _salvage(file: Path) -> _Salvage:
    """Every complete schema, channel and message of ``file`` up to the first cut record."""
    out = _Salvage()
    data = file.read_bytes()
    if not data.startswith(MCAP0_MAGIC):
        raise InputError(f'{file}: not an MCAP file')
    pos = len(MCAP0_MAGIC)
    while pos + _RECORD.size <= len(data):
        opcode, length = _RECORD.unpack_from(data, pos)
        start, end = pos + _RECORD.size, pos + _RECORD.size + length
        if end > len(data):
            break  # the record the kill cut short
        content = data[start:end]
        if opcode == Opcode.CHUNK:
            try:
                chunk = Chunk.read(ReadDataStream(BytesIO(content)))
                stream, size = get_chunk_data_stream(chunk, validate_crc=True)
                inner = stream.read(size)
                out.compression = out.compression or chunk.compression
                for op, body in _records(inner):
                    _keep(out, op, body)
            except _DAMAGED:  # CRC mismatch, corrupt compression, a broken inner record
                out.bad_chunks += 1
        elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
            break
        else:
            _keep(out, opcode, content)
        pos = end
    out.cut_bytes = len(data) - pos
    return out


def _records(data: bytes) -> Iterator[tuple[int, bytes]]:
    """(opcode, content) of the records in ``data``; McapError on a record cut short."""
    pos = 0
    while pos < len(data):
        opcode, length = _RECORD.unpack_from(data, pos)
        start = pos + _RECORD.size
        if start + length > len(data):
            raise McapError('record beyond the end of its chunk')
        yield opcode, data[start:start + length]
        pos = start + length


def _keep(out: _Salvage, opcode: int, content: bytes) -> None:
    """Add a schema, channel or message record to ``out`` (other records are index data)."""
    stream = ReadDataStream(BytesIO(content))
    if opcode == Opcode.SCHEMA:
        schema = Schema.read(stream)
        out.schemas[schema.id] = schema
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(stream)
        out.channels[channel.id] = channel
    elif opcode == Opcode.MESSAGE:
        message = Message.read(stream, len(content))
        if message.channel_id in out.channels:
            out.messages.append(message)


def _write(stream: BinaryIO, salvage: _Salvage) -> None:
    """A complete MCAP file (summary, indexes, chunk CRCs) with the salvaged records."""
    compression = CompressionType.ZSTD if salvage.compression == 'zstd' else \
        CompressionType.LZ4 if salvage.compression == 'lz4' else CompressionType.NONE
    writer = Writer(stream, chunk_size=CHUNK_BYTES, compression=compression)
    writer.start(profile='ros2', library='railgsa_ros recover')
    schema_ids = {sid: writer.register_schema(s.name, s.encoding, s.data)
                  for sid, s in salvage.schemas.items()}
    channel_ids = {cid: writer.register_channel(c.topic, c.message_encoding,
                                                schema_ids.get(c.schema_id, 0), c.metadata)
                   for cid, c in salvage.channels.items()}
    for m in salvage.messages:
        writer.add_message(channel_ids[m.channel_id], m.log_time, m.data, m.publish_time,
                           m.sequence)
    writer.finish()


@dataclass
class _Contents:
    """What a finished MCAP file holds: channels, schemas, messages per channel, log span."""

    channels: dict[int, Channel]
    schemas: dict[int, Schema]
    counts: dict[int, int]
    start_ns: int
    end_ns: int


def _contents(file: Path) -> _Contents:
    """The summary of a finished MCAP file; counted message by message when it has no
    statistics (some writers leave them out)."""
    with file.open('rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        if summary is None:
            raise InputError(f'{file}: an MCAP file without a summary')
        stats = summary.statistics
        if stats is not None:
            return _Contents(summary.channels, summary.schemas,
                             dict(stats.channel_message_counts), stats.message_start_time,
                             stats.message_end_time)
        counts: dict[int, int] = {}
        times = []
        for _, channel, message in reader.iter_messages():
            counts[channel.id] = counts.get(channel.id, 0) + 1
            times.append(message.log_time)
    return _Contents(summary.channels, summary.schemas, counts, min(times, default=0),
                     max(times, default=0))


def _message_count(file: Path) -> int:
    """Messages of a finished MCAP file."""
    return sum(_contents(file).counts.values())


def _segment(file: Path, topics: dict[str, tuple[str, list, str, int]]) -> Segment:
    """The metadata of one (finished or recovered) file; adds its topics' counts to
    ``topics`` (name -> type, offered QoS, type hash, count)."""
    found = _contents(file)
    for cid, channel in found.channels.items():
        schema = found.schemas.get(channel.schema_id)
        msgtype, qos, type_hash, count = topics.get(channel.topic, (
            schema.name if schema else '', _qos(channel), channel.metadata.get(
                'topic_type_hash', ''), 0))
        topics[channel.topic] = (msgtype, qos, type_hash, count + found.counts.get(cid, 0))
    return Segment(file.name, sum(found.counts.values()), found.start_ns, found.end_ns)


def _qos(channel: Channel) -> list:
    """The offered QoS profiles rosbag2 keeps as YAML text in the channel metadata."""
    try:
        profiles = yaml.safe_load(channel.metadata.get('offered_qos_profiles', '') or '[]')
    except yaml.YAMLError:
        return []
    return profiles if isinstance(profiles, list) else []
