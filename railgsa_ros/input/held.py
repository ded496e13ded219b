"""The held queue: IMU samples waiting for their speed decision, in arrival order.

A sample waits until its speed is final: until odometry newer than it has arrived, or IMU
stamps ``odom_timeout_s`` later, or HOLD_SAMPLES later samples, or a flush; so the decisions
depend on the data, not on how it was batched.
"""

from __future__ import annotations

import numpy as np

from railgsa_ros.input.sanitize import SMALL

HOLD_SAMPLES = 1 << 16  #: an IMU sample waits for odometry at most this many later samples
NO_STAMP = int(np.iinfo(np.int64).min)  #: the newest IMU stamp before any


class Held:
    """IMU samples waiting for their speed decision, in arrival order; ``received``: IMU
    samples given so far, ``newest_imu``: the newest finite one's stamp (ns) in this stream."""

    def __init__(self) -> None:
        self.received = 0
        self.newest_imu = NO_STAMP
        self.clear()

    def clear(self) -> None:
        self.stamps = np.zeros(0, np.int64)
        self.accel = np.zeros((0, 3))
        self.vertical = np.zeros(0)  # upward specific force (mounting projection), m/s^2
        self.frames = np.zeros(0, dtype=str)
        self.flags = np.zeros(0, np.uint8)  # input quality from gravity and rate checks
        self.arrival = np.zeros(0, np.int64)  # index of the sample since the policy started

    def __len__(self) -> int:
        return int(self.stamps.size)

    def extend(self, stamps: np.ndarray, accel: np.ndarray, vertical: np.ndarray,
               frames: np.ndarray, flags: np.ndarray, arrival: np.ndarray) -> None:
        if not len(self):  # the usual live case: nothing waits, no copy
            self.stamps, self.accel, self.frames = stamps, accel, frames
            self.vertical = vertical
            self.flags, self.arrival = flags, arrival
            return
        self.stamps = np.concatenate([self.stamps, stamps])
        self.accel = np.concatenate([self.accel, accel])
        self.vertical = np.concatenate([self.vertical, vertical])
        self.frames = np.concatenate([self.frames, frames])
        self.flags = np.concatenate([self.flags, flags])
        self.arrival = np.concatenate([self.arrival, arrival])

    def pop(self, count: int) -> tuple[np.ndarray, ...]:
        out = (self.stamps[:count], self.accel[:count], self.vertical[:count],
               self.frames[:count], self.flags[:count])
        if count == len(self):
            self.clear()
            return out
        self.stamps, self.accel = self.stamps[count:], self.accel[count:]
        self.vertical = self.vertical[count:]
        self.frames, self.flags = self.frames[count:], self.flags[count:]
        self.arrival = self.arrival[count:]
        return out

    def ready(self, newest_odom: int, timeout_ns: np.int64) -> int:
        """Number of held samples (a prefix) whose speed decision is final, given the newest
        odometry stamp and odom_timeout_s (ns)."""
        ready = (self.stamps <= newest_odom) | (self.arrival + HOLD_SAMPLES < self.received)
        if self.newest_imu > NO_STAMP + timeout_ns:
            ready |= self.stamps <= self.newest_imu - timeout_ns
        return len(self) if ready.all() else int(np.argmin(ready))

    def new_stream_at(self, stamps: np.ndarray, back_ns: int) -> int | None:
        """Index of the first IMU sample stamped more than ``back_ns`` before every earlier
        one (a time reset: a new stream, e.g. a bag played again), None without."""
        if stamps.size <= SMALL:
            newest = self.newest_imu
            for i, t in enumerate(stamps.tolist()):
                if newest != NO_STAMP and t < newest - back_ns:
                    return i
                newest = max(newest, t)
            return None
        running = np.maximum.accumulate(stamps)
        before = np.concatenate([[self.newest_imu], np.maximum(running[:-1], self.newest_imu)])
        jumps = np.flatnonzero((before != NO_STAMP) & (stamps < before - back_ns))
        return int(jumps[0]) if jumps.size else None
