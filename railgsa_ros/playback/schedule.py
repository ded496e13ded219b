"""Replay options, topic selection and remapping, and the pacing schedule (no ROS).

Times: bag stamps are int64 ns; ``due_ns`` is the wall-clock offset (ns) from the start of
playback at which an event is due: (bag time - window start) / rate. Looping restarts the window
one loop period later; ``/clock`` ticks are due every 1/clock_hz s of wall time and carry the bag
time of that instant.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
import math

from railgsa_ros.errors import ConfigError
from railgsa_ros.playback.source import TopicInfo

NS = 1_000_000_000
#: Loop period added after a single-message window (s of bag time).
SINGLE_MESSAGE_PERIOD_S = 1.0


@dataclass(frozen=True)
class PlaybackOptions:
    """What to play: rate (x real time), loop, window (s of bag time, duration 0 = to the end),
    topics (empty = all), remaps (from -> to) and the /clock rate (Hz, 0 = none)."""

    rate: float = 1.0
    loop: bool = False
    start_offset_s: float = 0.0
    duration_s: float = 0.0
    topics: tuple[str, ...] = ()
    remaps: tuple[tuple[str, str], ...] = ()
    clock_hz: float = 0.0

    def __post_init__(self) -> None:
        """Validate: ConfigError naming the field."""
        values = {'rate': self.rate, 'start_offset': self.start_offset_s,
                  'duration': self.duration_s, 'clock': self.clock_hz}
        for name, value in values.items():
            positive = name == 'rate'
            if not math.isfinite(value) or value < 0 or (positive and value == 0):
                raise ConfigError(f'{name}: invalid value {value!r} (must be finite and '
                                  f'{"> 0" if positive else ">= 0"})')


@dataclass(frozen=True)
class Message:
    """A message due at ``due_ns``: output topic, recorded stamp (ns) and CDR bytes."""

    due_ns: int
    topic: str
    stamp_ns: int
    data: bytes


@dataclass(frozen=True)
class ClockTick:
    """A /clock message due at ``due_ns`` carrying bag time ``stamp_ns``."""

    due_ns: int
    stamp_ns: int


def absolute(name: str) -> str:
    """A topic name with its leading slash."""
    return name if name.startswith('/') else '/' + name


def parse_remaps(specs: Iterable[str]) -> tuple[tuple[str, str], ...]:
    """``['FROM:=TO', ...]`` -> ((from, to), ...) with absolute names; ConfigError if malformed."""
    pairs = []
    for spec in specs:
        old, sep, new = spec.partition(':=')
        if not sep or not old.strip() or not new.strip():
            raise ConfigError(f'remap: {spec!r} is not FROM:=TO')
        pairs.append((absolute(old.strip()), absolute(new.strip())))
    return tuple(pairs)


def select_topics(topics: Mapping[str, TopicInfo], wanted: Sequence[str]) -> list[str]:
    """Bag topics to play: ``wanted`` (all when empty) that have messages; ConfigError for a
    wanted topic the bag does not hold."""
    if not wanted:
        return sorted(name for name, info in topics.items() if info.count)
    names = list(dict.fromkeys(absolute(w) for w in wanted))
    missing = [n for n in names if n not in topics]
    if missing:
        raise ConfigError(f'topics: {", ".join(missing)} not in the bag '
                          f'(it has {", ".join(sorted(topics))})')
    return [n for n in names if topics[n].count]


def window(start_ns: int, end_ns: int, options: PlaybackOptions) -> tuple[int, int]:
    """Bag-time window [lo, hi) in ns for a bag spanning [start_ns, end_ns]."""
    lo = start_ns + round(options.start_offset_s * NS)
    if lo > end_ns:
        raise ConfigError(f'start_offset: {options.start_offset_s} s is past the end of the bag '
                          f'({(end_ns - start_ns) / NS:.3f} s long)')
    hi = lo + round(options.duration_s * NS) if options.duration_s > 0 else end_ns + 1
    return lo, hi


def events(read: Callable[[], Iterable[tuple[str, int, bytes]]], lo: int, hi: int,
           options: PlaybackOptions) -> Iterator[Message | ClockTick]:
    """The playback schedule: messages from ``read()`` (a fresh time-ordered pass over the
    window [lo, hi) each call) remapped and due at their stamp / rate, merged with /clock ticks.

    With ``options.loop`` the window repeats forever; the loop period is the duration when one is
    given, else the span from lo to the last message plus one mean message interval.
    ConfigError if the window holds no message.
    """
    remap = dict(options.remaps)
    tick_ns = NS / options.clock_hz if options.clock_hz > 0 else math.inf
    ticks = 0
    period: int | None = None
    base = 0
    while True:
        first: int | None = None
        last = count = 0
        for topic, stamp, data in read():
            play = base + stamp - lo
            due = round(play / options.rate)
            while ticks * tick_ns <= due:
                tick_play = ticks * tick_ns * options.rate
                offset = tick_play - base if period is None else tick_play % period
                yield ClockTick(round(ticks * tick_ns), lo + round(offset))
                ticks += 1
            yield Message(due, remap.get(topic, topic), stamp, data)
            first = stamp if first is None else first
            last, count = stamp, count + 1
        if period is None:
            if first is None:
                raise ConfigError('no message in the selected topics and time window')
            period = _loop_period(lo, hi, first, last, count, options)
        if not options.loop:
            return
        base += period


def _loop_period(lo: int, hi: int, first: int, last: int, count: int,
                 options: PlaybackOptions) -> int:
    """Bag time (ns) from one loop start to the next."""
    if options.duration_s > 0:
        return hi - lo
    if count > 1:
        return last - lo + round((last - first) / (count - 1))
    return last - lo + round(SINGLE_MESSAGE_PERIOD_S * NS)
