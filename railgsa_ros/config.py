"""Reading YAML configuration files with one-line errors that name the file."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
import math
from pathlib import Path
from typing import Any

import yaml

from railgsa_ros.errors import ConfigError


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file; missing, unreadable or malformed files raise ConfigError naming it.

    Malformed includes what PyYAML lets escape as other exceptions: an impossible date
    (``2020-13-45``: ValueError), an integer of more than 4300 digits (ValueError), nesting
    deeper than Python's recursion limit (RecursionError).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror or exc})') from None
    except UnicodeDecodeError:
        raise ConfigError(f'{path}: not a UTF-8 text file') from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        where = f' (line {mark.line + 1})' if mark is not None else ''
        raise ConfigError(f'{path}: invalid YAML{where}') from None
    except RecursionError:
        raise ConfigError(f'{path}: invalid YAML (nested too deeply)') from None
    except (ValueError, TypeError, OverflowError) as exc:
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ConfigError(f'{path}: invalid YAML value ({reason})') from None


def key_list(keys: Iterable[Any]) -> str:
    """Mapping keys for a one-line message: sorted, comma-separated; keys that are not
    printable one-line strings (numbers, None, text with control characters) as repr."""
    return ', '.join(sorted(k if isinstance(k, str) and k.isprintable() else repr(k)
                            for k in keys))


def ros_parameters(doc: Any, node_name: str) -> dict[str, Any]:
    """Return ``doc[node_name]['ros__parameters']`` (or ``/**``), the ROS params-file layout."""
    if not isinstance(doc, dict):
        return {}
    for key in (node_name, f'/{node_name}', '/**'):
        section = doc.get(key)
        if isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict):
            return section['ros__parameters']
    return {}


def check_field(name: str, value: Any, default: Any, meta: Mapping[str, Any]) -> Any:
    """Coerce a dataclass field's ``value`` to the type of its ``default`` and check it against
    the field metadata: ``choices`` for strings, inclusive ``bounds`` for numbers (ConfigError
    naming the field otherwise)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ConfigError(f'{name}: expected true or false, got {value!r}')
        return value
    if isinstance(default, str):
        if not isinstance(value, str) or (meta['choices'] and value not in meta['choices']):
            allowed = ', '.join(meta['choices']) or 'a string'
            raise ConfigError(f'{name}: expected {allowed}, got {value!r}')
        return value
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f'{name}: expected a number, got {value!r}') from None
    except OverflowError:  # an int beyond the float range (its repr may be too long to print)
        raise ConfigError(f'{name}: expected a finite number, got an integer beyond the float '
                          'range') from None
    if isinstance(value, bool) or not math.isfinite(number):
        raise ConfigError(f'{name}: expected a finite number, got {value!r}')
    low, high = meta.get('bounds') or (-math.inf, math.inf)
    if not low <= number <= high:
        raise ConfigError(f'{name}: {value!r} is outside [{low:g}, {high:g}]')
    if isinstance(default, int):
        if number != int(number):
            raise ConfigError(f'{name}: expected an integer, got {value!r}')
        return int(number)
    return number
