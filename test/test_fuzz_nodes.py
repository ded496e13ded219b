"""Property-based fuzzing of the nodes' message handlers, in process: irregularity_node and
uncertainty_node get batches (0..N messages) of a running 1 kHz IMU stream with fuzzed messages
mixed in (stamps zero, negative, nanosec out of range, huge, backwards, duplicated; frame ids
empty, unicode, very long; accelerations NaN, +-inf, subnormal, 1e308; covariance patterns
with the -1/NaN sentinels; serialized bytes truncated, garbage, a foreign encapsulation), and
odometry messages with fuzzed stamps and speeds (and garbage bytes) before each batch, as the
reader thread hands them over. Nothing raises out of a handler, every value that reaches
track/irregularity, track/irregularity_band and track/sensitivity (recorded by a listener) is
finite, every IMU message is counted once and the core never fails (internal_error 0).
irregularity_node's feedback/no-band handler fuzz lives in test_irregularity_node.py.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import math
import threading
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from ros_helpers import NS, G, imu_msg, odometry_msg, serialized

pytestmark = pytest.mark.ros

FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=list(HealthCheck))
#: short band delay (designed at 40 m/s), sensitivity windows of 0.5 s, a cheap rule
COMMON = {'speed_mps': 40.0, 'min_design_speed_mps': 40.0, 'odom_timeout_s': 0.5}
UNCERTAINTY = {'rule': 'pem3', 'order': 1, 'window_length': 0.5, 'n_mc': 256,
               'germ_samples': 64, 'process_period_s': 1.0}
OUTPUTS = {'track/irregularity': ('point', 'x', 'z'),
           'track/irregularity_band': ('vector', 'x', 'y', 'z')}
REJECTED = ('malformed', 'nan', 'wrong_frame', 'saturated', 'stuck', 'out_of_order',
            'duplicate')

floats = st.one_of(st.floats(), st.sampled_from([np.nan, np.inf, -np.inf, 5e-324, 1e308]))
covariances = st.sampled_from([
    [0.0] * 9, [-1.0] + [0.0] * 8, [np.nan] + [0.0] * 8, [1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 1e-4],
    [-2e-4, 0, 0, 0, -2e-4, 0, 0, 0, -2e-4], [1e-4, 0, 0, 0, np.nan, 0, 0, 0, np.inf],
    [np.inf] * 9, [5e-324] * 9])
frames = st.one_of(st.sampled_from(['imu_link', '', 'base_link', 'imu_link ', 'x' * 10_000]),
                   st.text(max_size=40))
bad_messages = st.tuples(
    st.one_of(st.integers(-2**31, 2**31 - 1), st.sampled_from([0, -1, 2**31 - 1])),
    st.one_of(st.integers(0, 2**32 - 1), st.sampled_from([0, NS - 1, NS, 2**32 - 1])),
    frames, st.tuples(floats, floats, floats), covariances)
#: serialized messages no decoder reads: random bytes, a message cut at some byte, a valid
#: message with an XCDR2 / unknown encapsulation
garbage = st.one_of(st.binary(max_size=80), st.integers(0, 323).map(lambda n: ('cut', n)),
                    st.sampled_from([b'\x00\x07', b'\x00\x09', b'\x01\x00']).map(
                        lambda head: ('head', head)))
#: a batch: clean samples continuing the clock, with fuzzed messages (and bytes) at some
#: positions
batches = st.tuples(st.integers(0, 700), st.lists(st.tuples(st.floats(0, 1), bad_messages),
                                                  max_size=6),
                    st.sampled_from([1, 1, 1, 0, -1, 30]),  # clock step: on, dup, back, gap
                    st.lists(st.tuples(st.floats(0, 1), garbage), max_size=3))
#: odometry speeds: NaN/inf (rejected) and finite ones up to 1 km/s (beyond that the chainage
#: overflows: test_fuzz_core.py::test_absurd_odometry_speed_keeps_the_chainage_finite)
speeds = st.one_of(st.sampled_from([np.nan, np.inf, -np.inf]), st.floats(-1e3, 1e3),
                   st.floats(-80, 80))
odoms = st.lists(st.tuples(st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1), speeds,
                           st.booleans()), max_size=4)


class Clock:
    """The clean stream's next stamp (ns) and a seeded accelerometer."""

    def __init__(self) -> None:
        self.next_ns = 1_700_000_000 * NS
        self.rng = np.random.default_rng(0)
        self.sent = 0

    def batch(self, n: int, bad: list, step: int, junk: list) -> list[bytes]:
        """Serialized messages: the clean stream with ``bad`` messages and ``junk`` bytes."""
        stamps = self.next_ns + np.arange(n) * 1_000_000
        self.next_ns = int(stamps[-1]) + step * 1_000_000 if n else self.next_ns
        acc = G + 0.2 * self.rng.standard_normal(n)
        msgs = [imu_msg(*divmod(int(t), NS), 'imu_link', (0.0, 0.0, a), [-1.0] + [0.0] * 8)
                for t, a in zip(stamps.tolist(), acc.tolist(), strict=True)]
        for where, fields in bad:
            msgs.insert(int(where * len(msgs)), imu_msg(*fields))
        raws = serialized(msgs)
        valid = serialized([imu_msg(1, 0, 'imu_link', (0.0, 0.0, G), [0.0] * 9)])[0]
        for where, kind in junk:
            data = kind if isinstance(kind, bytes) else valid[:kind[1]] \
                if kind[0] == 'cut' else kind[1] + valid[2:]
            raws.insert(int(where * len(raws)), data)
        self.sent += len(raws)
        return raws

    def odom(self, rows: list) -> list[bytes]:
        """Serialized odometry: fuzzed stamps, or (flag) stamped at the stream's clock; one
        message cut short per batch."""
        raws = serialized([odometry_msg(*divmod(self.next_ns, NS), v) if at_clock else
                           odometry_msg(s, ns, v) for s, ns, v, at_clock in rows])
        return [*raws, raws[0][:40]] if raws else raws


class Listener:
    """Records the non-finite values and counts of the nodes' output topics."""

    def __init__(self, node: Any) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped, Vector3Stamped

        from railgsa_ros.nodes.qos import output_qos

        self.lock = threading.Lock()
        self.count = {t: 0 for t in (*OUTPUTS, 'track/sensitivity')}
        self.bad: list[str] = []
        node.create_subscription(PointStamped, 'track/irregularity',
                                 self._sample('track/irregularity'), output_qos(5000))
        node.create_subscription(Vector3Stamped, 'track/irregularity_band',
                                 self._sample('track/irregularity_band'), output_qos(5000))
        node.create_subscription(DiagnosticArray, 'track/sensitivity', self._sensitivity,
                                 output_qos(1000))

    def _sample(self, topic: str) -> Callable[[Any], None]:
        member, *names = OUTPUTS[topic]

        def record(msg: Any) -> None:
            part = getattr(msg, member)
            values = [getattr(part, n) for n in names]
            if member == 'point':  # x chainage always finite; z NaN exactly when y = INVALID
                ok = math.isfinite(part.x) and math.isfinite(part.z) == (part.y != 2)
            else:  # the band: all finite, or all NaN (an INVALID sample)
                ok = all(map(math.isfinite, values)) or all(map(math.isnan, values))
            with self.lock:
                self.count[topic] += 1
                if not ok:
                    self.bad.append(f'{topic}: {part}')
        return record

    def _sensitivity(self, msg: Any) -> None:
        with self.lock:
            self.count['track/sensitivity'] += 1
            for status in msg.status:
                for kv in status.values:
                    try:
                        finite = math.isfinite(float(kv.value))
                    except ValueError:
                        continue  # text values (qoi, rule)
                    if not finite:
                        self.bad.append(f'track/sensitivity {status.name} {kv.key}={kv.value}')


@pytest.fixture
def rig(ros_context: Any, spin: Callable, wait_for: Callable) -> Iterator[Callable]:
    """``rig(node_cls, params)`` -> (node under test, listener); the node is not spun: the
    test calls its handlers, the listener's executor records the outputs."""
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    listen_node = spin(Node('fuzz_listener', context=ros_context))
    listener = Listener(listen_node)
    made: list[Any] = []

    def make(node_cls: type, params: dict, topics: tuple[str, ...]) -> tuple[Any, Listener]:
        node = node_cls(context=ros_context, parameter_overrides=[
            Parameter(k, value=v) for k, v in {**COMMON, **params}.items()])
        made.append(node)
        assert wait_for(lambda: all(listen_node.count_publishers(t) > 0 for t in topics), 15.0)
        return node, listener

    yield make
    for node in made:
        node.destroy_node()


def run_fuzz(node: Any, finite: Callable[[Any], bool]) -> None:
    """Feed the fuzzed odometry and IMU batches; check the returns and the counters."""
    clock = Clock()

    @FUZZ
    @given(batches, odoms)
    def handle(batch: tuple, odom_rows: list) -> None:
        out = node.process(clock.batch(*batch), clock.odom(odom_rows))
        assert out is None or finite(out)

    handle()
    totals = node.counters()
    assert totals['received'] == clock.sent
    policy = node.policy if hasattr(node, 'policy') else node.stream.policy
    assert totals['received'] == totals.get('accepted', 0) + sum(
        totals.get(r, 0) for r in REJECTED) + policy.held, totals  # each message once (or
    # still held by the policy for its speed or noise decision)
    assert totals.get('internal_error', 0) == 0, totals
    assert totals.get('malformed', 0) > 0, totals  # outputs published once any was emitted
    assert totals.get('published', 0) > 0 or totals.get('emitted', 0) == 0, totals
    assert totals.get('odom_malformed', 0) > 0, totals  # NaN/inf speeds and bad stamps


def test_irregularity_node_handlers(rig: Callable, wait_for: Callable) -> None:
    from railgsa_ros.nodes.irregularity_node import IrregularityNode

    node, listener = rig(IrregularityNode, {'wrong_frame_policy': 'accept'},
                         ('track/irregularity',))
    run_fuzz(node, lambda out: bool(  # u NaN exactly where INVALID
        np.all(np.isfinite(out.u_m) == (out.quality != 2))
        and np.all(np.isfinite(out.chainage_m))))
    assert wait_for(lambda: listener.count['track/irregularity']
                    >= node.counters().get('published', 0), 10.0)
    assert listener.bad == []


def test_uncertainty_node_handlers(rig: Callable, wait_for: Callable) -> None:
    from railgsa_ros.nodes.uncertainty_node import UncertaintyNode

    node, listener = rig(UncertaintyNode, UNCERTAINTY,
                         ('track/irregularity_band', 'track/sensitivity'))
    run_fuzz(node, lambda band: all(  # the band NaN exactly where INVALID
        bool(np.all(np.isfinite(getattr(band, f)) == (band.quality != 2))) for f in
        ('lower_m', 'mean_m', 'upper_m')) and bool(np.all(np.isfinite(band.chainage_m))))
    assert wait_for(lambda: listener.count['track/irregularity_band']
                    >= node.counters().get('published', 0), 10.0)
    if node.counters().get('valid', 0) + node.counters().get('degraded', 0):  # windows take
        assert wait_for(lambda: listener.count['track/sensitivity'] > 0, 10.0)  # those only
    assert listener.bad == []
