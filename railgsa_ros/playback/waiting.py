"""When a replay may start: its publishers matched by the subscribers that are there (no ROS).

A node that is already running is in the ROS graph (discovered) before its subscription has
matched a new publisher: playing at once loses the first messages (about 0.7 s on loopback).
So a replay waits until, for every played topic, the matched subscribers number at least
``min_subscribers`` and at least the QoS-compatible subscriptions in the graph, and the counts
have stayed so for ``settle_s`` (participants discovered in one burst match a little apart,
and the readers' own side of a match comes later than the writer's); it gives up after the
timeout and plays anyway (the caller warns).
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

WAIT_S = 10.0  #: default longest wait before playing, s (``railgsa replay --wait-timeout``)
#: counts unchanged this long before playing, s: the publisher side's match is what the graph
#: shows; a BEST_EFFORT reader drops samples until its own side has matched the writer too,
#: which its process does a little later (up to ~0.6 s measured under load: 617 of 9000 IMU
#: samples lost with 0.25 s)
SETTLE_S = 1.0

#: topic -> (matched subscriptions of our publisher, compatible subscriptions in the graph)
Counts = Mapping[str, tuple[int, int]]


@dataclass
class SubscriberWait:
    """Feed ``update(counts, now_s)`` until it returns True (ready to play). Topics in
    ``required`` need ``min_subscribers`` matched; the others (``/clock``) only need every
    subscriber in the graph matched."""

    required: Collection[str]
    min_subscribers: int = 1
    settle_s: float = SETTLE_S
    lonely: list[str] = field(default_factory=list)  #: topics still short, after update
    _last: dict[str, tuple[int, int]] | None = None
    _since: float | None = None

    def update(self, counts: Counts, now_s: float) -> bool:
        """Whether every topic is matched and the counts stayed the same for settle_s."""
        self.lonely = [t for t, (matched, graph) in counts.items() if matched < max(
            graph, self.min_subscribers if t in self.required else 0)]
        counts = dict(counts)
        if self.lonely or counts != self._last:
            self._last, self._since = counts, None if self.lonely else now_s
            return False
        since = self._since  # None only while a topic is short (returned above)
        return since is not None and now_s - since >= self.settle_s
