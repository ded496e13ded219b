"""``railgsa info BAG``: what a rosbag2 bag holds and how its clocks ran, like ``ros2 bag info``.

Per topic: type, message count and the rate from the header stamps (median, and the slowest and
fastest interval; log times where the publisher left every stamp zero or the type has no
header layout the bag readers decode). IMU topics also get their stamp gaps: intervals longer
than GAP_PERIODS median periods, counted, with the largest and where it is. NavSatFix topics get
their fixes: count, status, first and last position. For the bag: storage (mcap or sqlite3),
compression (rosbag2's file/message compression, or the MCAP chunks'), files and sizes, start,
end and duration of the log times. ``--json`` prints the same for machines (times as ISO 8601
UTC, durations in ``_s``, rates in ``_hz``). Works on MCAP and sqlite3 bags, directories and
bare files; an unreadable bag is one line and exit 2.
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the command imports its modules when it runs (fast --help)
    import numpy as np

#: an IMU stamp interval longer than this many median periods is a gap
GAP_PERIODS = 1.5
IMU_TYPE = 'sensor_msgs/msg/Imu'
NAV_SAT_FIX = 'sensor_msgs/msg/NavSatFix'
#: sensor_msgs/NavSatStatus values
FIX_STATUS = {-1: 'no_fix', 0: 'fix', 1: 'sbas_fix', 2: 'gbas_fix'}
TIMES = {'header': 'header stamps', 'log_time': 'log times'}


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``info`` subcommand."""
    p = subparsers.add_parser(
        'info', help='topics, types, counts, rates, gaps and GNSS of a bag (as ros2 bag info)',
        description='Print what a rosbag2 bag (MCAP or sqlite3) holds: storage, compression, '
                    'files, duration; per topic the type, message count and rate from the '
                    f'header stamps (median, min, max); IMU stamp gaps over {GAP_PERIODS:g} '
                    'periods (count, largest, where); NavSatFix fixes (count, status, first '
                    'and last position).')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or .mcap/.db3 file')
    p.add_argument('--json', action='store_true', help='print the result as JSON')
    p.set_defaults(func=run)


@dataclass(frozen=True)
class Rate:
    """Message rate in Hz from the stamp intervals: 1 / median, 1 / longest, 1 / shortest
    (intervals > 0 only); ``backwards``: intervals <= 0 (stamps repeated or out of order)."""

    median_hz: float
    min_hz: float
    max_hz: float
    backwards: int


@dataclass(frozen=True)
class Gaps:
    """IMU stamp intervals longer than ``threshold_s`` (GAP_PERIODS median periods)."""

    threshold_s: float
    count: int
    largest_s: float | None = None
    largest_at: str | None = None  #: stamp of the sample before the largest gap (ISO UTC)
    largest_after_s: float | None = None  #: that stamp, from the topic's first stamp


@dataclass(frozen=True)
class Gnss:
    """NavSatFix messages: how many carry a fix (status >= 0), per status, the first and last
    fix's (latitude, longitude) in degrees (WGS84)."""

    fixes: int
    status: dict[str, int]
    first_fix_deg: tuple[float, float] | None
    last_fix_deg: tuple[float, float] | None


@dataclass(frozen=True)
class Topic:
    """One topic: its type, count, where its times come from ('header' or 'log_time'), the
    first and last of them (ISO UTC), the rate, and gaps (IMU) or fixes (NavSatFix)."""

    topic: str
    msgtype: str
    count: int
    times: str
    first: str | None
    last: str | None
    rate: Rate | None
    gaps: Gaps | None = None
    gnss: Gnss | None = None


@dataclass(frozen=True)
class BagInfo:
    """A bag: storage id, compression, files (name -> bytes), the log-time span, topics."""

    path: str
    storage: str
    compression: str
    files: dict[str, int]
    start: str | None
    end: str | None
    duration_s: float
    messages: int
    topics: list[Topic]


def iso(ns: int) -> str:
    """Nanoseconds since the epoch as ISO 8601 UTC to the microsecond."""
    return datetime.fromtimestamp(ns // 1000 / 1e6, tz=UTC).isoformat(timespec='microseconds')


def rate(stamps_ns: np.ndarray) -> Rate | None:
    """The rate of a stamp series in bag order (None with fewer than two intervals > 0)."""
    import numpy as np

    dt = np.diff(stamps_ns)
    forward = dt[dt > 0]
    if forward.size < 2:
        return None
    return Rate(1e9 / float(np.median(forward)), 1e9 / float(forward.max()),
                1e9 / float(forward.min()), int(np.count_nonzero(dt <= 0)))


def gaps(stamps_ns: np.ndarray, median_hz: float) -> Gaps:
    """The intervals of a stamp series longer than GAP_PERIODS median periods."""
    import numpy as np

    dt = np.diff(stamps_ns)
    threshold = GAP_PERIODS * 1e9 / median_hz
    over = np.flatnonzero(dt > threshold)
    if over.size == 0:
        return Gaps(threshold / 1e9, 0)
    at = int(over[np.argmax(dt[over])])
    return Gaps(threshold / 1e9, int(over.size), float(dt[at]) / 1e9, iso(int(stamps_ns[at])),
                float(stamps_ns[at] - stamps_ns[0]) / 1e9)


def gnss(status: np.ndarray, latitude: np.ndarray, longitude: np.ndarray) -> Gnss:
    """Fix counts and first/last fix position of NavSatFix fields (N,) each."""
    import numpy as np

    fixed = np.flatnonzero((status >= 0) & np.isfinite(latitude) & np.isfinite(longitude))
    values, counts = np.unique(status, return_counts=True)
    ends = [(float(latitude[i]), float(longitude[i])) for i in fixed[[0, -1]]] \
        if fixed.size else [None, None]
    return Gnss(int(fixed.size),
                {FIX_STATUS.get(int(v), str(int(v))): int(c) for v, c in zip(values, counts,
                                                                            strict=True)},
                *ends)


def topic_info(topic: str, msgtype: str, log_ns: np.ndarray, stamps_ns: np.ndarray | None,
               fix: Gnss | None = None) -> Topic:
    """A Topic from its log times and header stamps (None: no header layout); all-zero
    stamps (a publisher that does not stamp) give way to the log times."""
    import numpy as np

    source = 'header'
    if stamps_ns is None or (stamps_ns.size and not np.any(stamps_ns)):
        stamps_ns, source = log_ns, 'log_time'
    first, last = (iso(int(stamps_ns.min())), iso(int(stamps_ns.max()))) if stamps_ns.size \
        else (None, None)
    measured = rate(stamps_ns)
    return Topic(topic, msgtype, int(log_ns.size), source, first, last, measured,
                 gaps(stamps_ns, measured.median_hz) if measured and msgtype == IMU_TYPE else None,
                 fix)


def read_topics(path: Path) -> tuple[list[Topic], tuple[int, int] | None]:
    """Every topic of the bag, and the first and last log time (ns; None: no message): the
    log times of all topics from the raw messages (nothing decoded), the header stamps of the
    types the readers decode in chunks (their fixed layouts and NavSatFix)."""
    import numpy as np

    from railgsa_ros.bag.messages import LAYOUTS
    from railgsa_ros.bag.reader import GnssFixes, iter_topics, open_bag

    with open_bag(path) as reader:
        types = {topic: t.msgtype or '?' for topic, t in reader.topics.items()}
        logs: dict[str, list[int]] = {t: [] for t in types}
        for conn, log_ns, _ in reader.messages():
            logs[conn.topic].append(log_ns)
    every_log = [t for times in logs.values() for t in times[:1] + times[-1:]]
    span = (min(every_log), max(every_log)) if every_log else None
    stamped = {t: m for t, m in types.items() if m in LAYOUTS or m == NAV_SAT_FIX}
    stamps: dict[str, list[np.ndarray]] = {t: [] for t in stamped}
    fixes: dict[str, list[GnssFixes]] = {t: [] for t, m in stamped.items() if m == NAV_SAT_FIX}
    for batch in iter_topics(path, stamped):
        for topic, data in batch.items():
            stamps[topic].append(data.stamps_ns)
            if isinstance(data, GnssFixes):
                fixes[topic].append(data)
    out = []
    for topic, msgtype in sorted(types.items()):
        every = GnssFixes.concat(fixes[topic]) if topic in fixes else None
        out.append(topic_info(
            topic, msgtype, np.array(logs[topic], dtype=np.int64),
            np.concatenate([np.zeros(0, np.int64), *stamps[topic]]) if topic in stamps
            else None,
            None if every is None else gnss(every.status, every.latitude_deg,
                                             every.longitude_deg)))
    return out, span


def storage(path: Path, files: list[Path]) -> tuple[str, str]:
    """(storage id, compression) of a bag: rosbag2's file/message compression from
    metadata.yaml, else the MCAP chunks' compression ('none' when there is none)."""
    import yaml

    meta = path / 'metadata.yaml' if path.is_dir() else path.parent / 'metadata.yaml'
    info: dict[str, Any] = {}
    if meta.is_file():
        info = (yaml.safe_load(meta.read_text(encoding='utf-8')) or {}).get(
            'rosbag2_bagfile_information', {})
    kind = info.get('storage_identifier') or ('mcap' if files[0].suffix == '.mcap'
                                              else 'sqlite3')
    if info.get('compression_format'):
        return kind, f"{info['compression_format']} ({info.get('compression_mode') or '?'} mode)"
    if kind != 'mcap':
        return kind, 'none'
    from mcap.reader import make_reader

    chunks: set[str] = set()
    for file in files:
        with file.open('rb') as f:
            summary = make_reader(f).get_summary()
        chunks.update(c.compression for c in (summary.chunk_indexes if summary else []))
    named = sorted(c for c in chunks if c)
    return kind, f"{', '.join(named)} (MCAP chunks)" if named else 'none'


def bag_info(path: str | Path) -> BagInfo:
    """Everything ``railgsa info`` prints about the bag at ``path``; InputError when it is not a
    readable rosbag2 bag."""
    from railgsa_ros.bag.reader import storage_paths

    path = Path(path)
    given = storage_paths(path)
    files = given if given[0].is_file() else sorted(
        p for p in given[0].iterdir() if p.suffix in ('.mcap', '.db3'))
    topics, span = read_topics(path)
    kind, compression = storage(path, files)
    start, end = span or (0, 0)
    return BagInfo(str(path), kind, compression, {f.name: f.stat().st_size for f in files},
                   iso(start) if span else None, iso(end) if span else None, (end - start) / 1e9,
                   sum(t.count for t in topics), topics)


def size(n: float) -> str:
    """Bytes as B, KiB, MiB or GiB."""
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if n < 1024 or unit == 'GiB':
            return f'{n:.0f} {unit}' if unit == 'B' else f'{n:.1f} {unit}'
        n /= 1024
    raise AssertionError('unreachable')


def describe(info: BagInfo) -> str:
    """The text ``railgsa info`` prints: the bag as ``ros2 bag info`` does, then a line per
    topic and its gaps or fixes."""
    lines = [f'Files:             {", ".join(info.files)}',
             f'Bag size:          {size(sum(info.files.values()))}',
             f'Storage id:        {info.storage}',
             f'Compression:       {info.compression}',
             f'Duration:          {info.duration_s:.3f} s',
             f'Start:             {info.start or "-"}',
             f'End:               {info.end or "-"}',
             f'Messages:          {info.messages}',
             'Topic information:']
    for t in info.topics:
        line = f'  {t.topic} | {t.msgtype} | {t.count} msgs'
        if t.rate is not None:
            line += (f' | {t.rate.median_hz:.6g} Hz (min {t.rate.min_hz:.6g}, max '
                     f'{t.rate.max_hz:.6g}; {TIMES[t.times]})')
            if t.rate.backwards:
                line += f' | {t.rate.backwards} stamps not after the previous'
        lines.append(line)
        if t.gaps is not None:
            lines.append(f'    {gap_text(t.gaps)}')
        if t.gnss is not None:
            lines.append(f'    {gnss_text(t.gnss, t.count)}')
    return '\n'.join(lines)


def gap_text(gap: Gaps) -> str:
    """One line on an IMU topic's stamp gaps."""
    text = f'gaps over {GAP_PERIODS:g} periods ({gap.threshold_s * 1e3:.4g} ms): {gap.count}'
    if gap.count:
        text += (f', largest {gap.largest_s:.6g} s after the sample at {gap.largest_at} '
                 f'({gap.largest_after_s:.3f} s from the first)')
    return text


def gnss_text(fix: Gnss, count: int) -> str:
    """One line on a NavSatFix topic's fixes."""
    status = ', '.join(f'{k} {v}' for k, v in fix.status.items())
    text = f'GNSS: {fix.fixes} fixes of {count} ({status})'
    if fix.first_fix_deg is not None and fix.last_fix_deg is not None:
        text += (f'; first {fix.first_fix_deg[0]:.7f}, {fix.first_fix_deg[1]:.7f}; last '
                 f'{fix.last_fix_deg[0]:.7f}, {fix.last_fix_deg[1]:.7f} (lat, lon deg)')
    return text


def run(args: argparse.Namespace) -> int:
    """Print the bag's information, as text or JSON."""
    info = bag_info(args.bag)
    print(json.dumps(asdict(info), indent=2) if args.json else describe(info))
    return 0
