"""Checklist items: status, measured value, expected range; text and JSON renderings."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
import json

PASS, WARN, FAIL = 'PASS', 'WARN', 'FAIL'
_RANK = {PASS: 0, WARN: 1, FAIL: 2}


@dataclass(frozen=True)
class Item:
    """One line of the checklist: what was checked, the verdict, the measured value and the
    expected range (both as text with units) and a hint for the technician when not PASS."""

    name: str
    status: str
    value: str
    expected: str
    hint: str = ''


def overall(items: Sequence[Item]) -> str:
    """The worst status of ``items`` (PASS when empty)."""
    return max((i.status for i in items), key=_RANK.__getitem__, default=PASS)


def exit_code(items: Sequence[Item]) -> int:
    """0 unless an item FAILed (then 1); warnings do not fail the check."""
    return 1 if overall(items) == FAIL else 0


def format_items(items: Sequence[Item]) -> str:
    """The checklist as aligned text lines plus a result line."""
    width = max((len(i.name) for i in items), default=0)
    lines = []
    for i in items:
        lines.append(f'{i.status}  {i.name:<{width}}  {i.value}  (expected {i.expected})')
        if i.hint and i.status != PASS:
            lines.append(f'{"":6}{"":<{width}}  -> {i.hint}')
    counts = {s: sum(i.status == s for i in items) for s in (FAIL, WARN)}
    lines.append(f'result: {overall(items)} ({counts[FAIL]} failed, {counts[WARN]} warnings)')
    return '\n'.join(lines)


def items_json(items: Sequence[Item]) -> str:
    """``{"status": worst, "items": [...]}`` as JSON text."""
    return json.dumps({'status': overall(items), 'items': [asdict(i) for i in items]},
                      indent=2)
