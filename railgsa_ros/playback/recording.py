"""Writing received CDR messages to a rosbag2 MCAP bag that stays readable (no ROS).

The bag is a directory ``OUT`` with ``OUT_0.mcap``, ``OUT_1.mcap``, ... and ``metadata.yaml``
(rosbag2 version 9), as ``ros2 bag record -s mcap`` writes it. A new file starts every ``split_s``
seconds of log time, and ``metadata.yaml`` is rewritten atomically each time a file is finished,
so a crash or a full disk loses at most the file in progress. A write error stops the recorder:
the broken file is renamed ``*.mcap.partial`` and ConfigError names it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from contextlib import suppress
from dataclasses import dataclass, field
import errno
import os
from pathlib import Path
from typing import BinaryIO

from mcap.writer import CompressionType, Writer
from rosbags.interfaces import Qos
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

from railgsa_ros.bag.messages import typestore
from railgsa_ros.errors import ConfigError

#: MCAP chunk size (bytes): about 2.5 s of a 1 kHz Imu stream.
CHUNK_BYTES = 1 << 20


@dataclass
class TopicSpec:
    """A recorded topic: name, type, offered QoS, RIHS01 type hash ('' if unknown) and the
    message count in finished files."""

    name: str
    msgtype: str
    offered_qos: list[Qos] = field(default_factory=list)
    type_hash: str = ''
    count: int = 0


@dataclass
class Segment:
    """One finished storage file: name, message count and log-time span (ns)."""

    name: str
    count: int
    start_ns: int
    end_ns: int


def message_definition(msgtype: str) -> str:
    """The ros2msg text of ``msgtype`` with its dependencies ('' for a type rosbags lacks)."""
    try:
        return typestore().generate_msgdef(msgtype, ros_version=2)[0]
    except (KeyError, ValueError):
        return ''


class BagRecorder:
    """Appends messages to a split MCAP rosbag2 bag; ``close()`` finishes it."""

    def __init__(self, path: str | Path, split_s: float = 60.0, compress: bool = True) -> None:
        """Create the bag directory (ConfigError if it exists or cannot be created)."""
        if not split_s > 0:
            raise ConfigError(f'split: invalid value {split_s!r} (must be > 0 s)')
        self.path = Path(path)
        self.split_ns = round(split_s * 1e9)
        self.compression = CompressionType.ZSTD if compress else CompressionType.NONE
        self.topics: dict[str, TopicSpec] = {}
        self.segments: list[Segment] = []
        self._file: BinaryIO | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._pending: dict[str, int] = {}
        self._seg_start = self._seg_end = 0
        self.failed: str | None = None
        if self.path.exists():
            raise ConfigError(f'{self.path}: output already exists')
        try:
            self.path.mkdir(parents=True)
        except OSError as exc:
            raise ConfigError(f'{self.path}: cannot create the bag ({_why(exc)})') from None

    @property
    def message_count(self) -> int:
        """Messages written so far, including the file in progress."""
        return sum(t.count for t in self.topics.values()) + sum(self._pending.values())

    def add_topic(self, spec: TopicSpec) -> None:
        """Declare a topic before writing to it."""
        self.topics[spec.name] = spec
        writer = self._writer
        if writer is not None:
            self._guarded(lambda: self._register(writer, spec))

    def write(self, topic: str, log_ns: int, data: bytes) -> None:
        """Append one message received at ``log_ns`` (ns); starts a new file when due."""
        self._guarded(lambda: self._write(topic, log_ns, data))

    def tick(self, now_ns: int) -> None:
        """Push buffered data to disk and finish the file in progress if it is ``split_s`` old."""
        def flush() -> None:
            if self._writer is None or self._file is None:
                return
            if now_ns - self._seg_start >= self.split_ns:
                self._finish()
            else:
                self._writer.flush()
                os.fsync(self._file.fileno())
        self._guarded(flush)

    def close(self) -> None:
        """Finish the file in progress and write metadata.yaml (nothing more after a failure)."""
        if self.failed:
            return
        self._guarded(self._finish)
        if not self.segments:
            self._guarded(self._write_metadata)

    def _write(self, topic: str, log_ns: int, data: bytes) -> None:
        """Append, opening or splitting files as needed."""
        if self._writer is not None and log_ns - self._seg_start >= self.split_ns:
            self._finish()
        writer = self._writer or self._open(log_ns)
        writer.add_message(self._channels[topic], log_ns, data, log_ns)
        self._pending[topic] = self._pending.get(topic, 0) + 1
        self._seg_end = max(self._seg_end, log_ns)

    def _file_path(self) -> Path:
        """Path of the file in progress."""
        return self.path / f'{self.path.name}_{len(self.segments)}.mcap'

    def _open(self, start_ns: int) -> Writer:
        """Start a new storage file and register every known topic in it; its writer."""
        self._file = open(self._file_path(), 'xb')  # noqa: SIM115 - closed in _finish
        writer = self._writer = Writer(self._file, chunk_size=CHUNK_BYTES,
                                       compression=self.compression)
        writer.start(profile='ros2', library='railgsa_ros')
        self._channels, self._pending = {}, {}
        self._seg_start = self._seg_end = start_ns
        for spec in self.topics.values():
            self._register(writer, spec)
        return writer

    def _register(self, writer: Writer, spec: TopicSpec) -> None:
        """Schema and channel of ``spec`` in the file in progress."""
        schema = writer.register_schema(spec.msgtype, 'ros2msg',
                                              message_definition(spec.msgtype).encode())
        metadata = {'offered_qos_profiles': _qos_yaml(spec.offered_qos)}
        if spec.type_hash:
            metadata['topic_type_hash'] = spec.type_hash
        self._channels[spec.name] = writer.register_channel(spec.name, 'cdr', schema, metadata)

    def _finish(self) -> None:
        """Finish the file in progress (if any) and rewrite metadata.yaml."""
        if self._writer is None or self._file is None:
            return
        self._writer.finish()
        os.fsync(self._file.fileno())
        self._file.close()
        self.segments.append(Segment(self._file_path().name, sum(self._pending.values()),
                                      self._seg_start, self._seg_end))
        for topic, count in self._pending.items():
            self.topics[topic].count += count
        self._writer, self._file, self._pending = None, None, {}
        self._write_metadata()

    def _write_metadata(self) -> None:
        """Write metadata.yaml (version 9) for the finished files, atomically."""
        write_metadata(self.path, self.segments, [
            topic_entry(t.name, t.msgtype, dump_qos_v9(t.offered_qos), t.type_hash, t.count)
            for t in self.topics.values()])

    def _guarded(self, action: Callable[[], None]) -> None:
        """Run ``action``; on OSError abandon the file in progress and raise ConfigError."""
        try:
            action()
        except OSError as exc:
            raise ConfigError(self._abandon(exc)) from None

    def _abandon(self, exc: OSError) -> str:
        """Close and rename the broken file; the message for the user."""
        broken = None
        if self._file is not None:
            broken = self._file_path()
            with suppress(OSError):
                self._file.close()
            with suppress(OSError):
                broken.rename(broken.with_name(broken.name + '.partial'))
        self._writer, self._file, self._pending = None, None, {}
        kept = sum(s.count for s in self.segments)
        target = broken or self.path / 'metadata.yaml'
        self.failed = (f'{target}: write failed ({_why(exc)}); recording stopped, {kept} '
                       f'messages in {len(self.segments)} finished file(s) of {self.path} stay '
                       'readable')
        return self.failed


def topic_entry(name: str, msgtype: str, qos: Sequence[Mapping[str, object]], type_hash: str,
                count: int) -> dict:
    """One ``topics_with_message_count`` entry of metadata.yaml (QoS as dumped for version 9)."""
    return {'topic_metadata': {'name': name, 'type': msgtype, 'serialization_format': 'cdr',
                               'offered_qos_profiles': qos, 'type_description_hash': type_hash},
            'message_count': count}


def write_metadata(path: Path, segments: list[Segment], topics: list[dict]) -> None:
    """Write ``path/metadata.yaml`` (rosbag2 version 9, MCAP) listing ``segments`` with the
    ``topics`` entries (``topic_entry``), atomically (temporary file, fsync, rename)."""
    start = min((s.start_ns for s in segments), default=0)
    end = max((s.end_ns for s in segments), default=0)
    info = {
        'version': 9, 'storage_identifier': 'mcap',
        'relative_file_paths': [s.name for s in segments],
        'duration': {'nanoseconds': end - start},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': sum(s.count for s in segments),
        'topics_with_message_count': topics,
        'compression_format': '', 'compression_mode': '',
        'files': [{'path': s.name, 'starting_time': {'nanoseconds_since_epoch': s.start_ns},
                   'duration': {'nanoseconds': s.end_ns - s.start_ns},
                   'message_count': s.count} for s in segments],
        'custom_data': None, 'ros_distro': 'jazzy'}
    tmp = path / 'metadata.yaml.tmp'
    with open(tmp, 'w', encoding='utf-8') as out:
        yaml.safe_dump({'rosbag2_bagfile_information': info}, out, sort_keys=False)
        out.flush()
        os.fsync(out.fileno())
    tmp.replace(path / 'metadata.yaml')


def _qos_yaml(profiles: list[Qos]) -> str:
    """offered_qos_profiles as the YAML text rosbag2 stores in MCAP channel metadata."""
    return yaml.safe_dump(dump_qos_v9(profiles), sort_keys=False) if profiles else ''


def _why(exc: OSError) -> str:
    """Short reason for an OSError."""
    return exc.strerror or errno.errorcode.get(exc.errno or 0, str(exc))
