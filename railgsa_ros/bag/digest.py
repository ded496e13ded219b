"""What a bag holds, as a short digest: a copy of a bag (another path, name or storage format)
has the same digest, another recording a different one.

The digest is SHA-256 over every topic's name, type and message count and over the log time,
topic and serialized bytes of the first ``FIRST`` messages and of every message of the last
``LAST_NS`` of the recording. It reads a few thousand messages whatever the bag's length (the
start, and the end through the storage's time index), not the whole bag. That is enough to
tell recordings apart: the messages carry nanosecond stamps and sensor noise, so two different
recordings never share their first messages byte for byte, and a recording cut short or
continued differs in its counts and its end. Not detected: a copy edited in the middle with
every count kept (not a copy, then, but no defence against it either).
"""

from __future__ import annotations

import hashlib
from itertools import islice
from pathlib import Path

from railgsa_ros.bag.reader import open_bag

FIRST = 1000  # messages hashed from the start
LAST_NS = 10**9  # and every message of the last second


def bag_digest(path: str | Path) -> str:
    """Hex SHA-256 of the bag's content (module docstring); InputError naming the bag when it
    cannot be read."""
    sha = hashlib.sha256()
    with open_bag(path) as reader:
        for topic in sorted(f'{c.topic}\0{c.msgtype}\0{c.msgcount}\0'
                            for c in reader.connections):
            sha.update(topic.encode())
        last = reader.end_time - LAST_NS
        for part in (islice(reader.messages(), FIRST), reader.messages(start=last)):
            for conn, log_time, raw in part:
                sha.update(f'{conn.topic}\0{log_time}\0{len(raw)}\0'.encode())
                sha.update(raw)
    return sha.hexdigest()
