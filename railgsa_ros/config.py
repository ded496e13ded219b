"""Reading YAML configuration files with one-line errors that name the file."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from difflib import get_close_matches
import math
from pathlib import Path
import re
import stat
from typing import Any

import yaml

from railgsa_ros.errors import ConfigError

MAX_BYTES = 1 << 20  # configuration files are a few kB; a larger one is not one
_NAME = re.compile(r'[\w./*~-]{1,64}')  # what a parameter, field or section name looks like


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file; ConfigError naming it, in one line that quotes nothing of the file,
    when it is missing, unreadable, not a regular file (a device such as /dev/zero, a pipe, a
    directory), larger than MAX_BYTES, not UTF-8 or malformed.

    Malformed includes what PyYAML lets escape as other exceptions: an impossible date
    (``2020-13-45``: ValueError), an integer of more than 4300 digits (ValueError), nesting
    deeper than Python's recursion limit (RecursionError).
    """
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode):
            raise ConfigError(f'{path}: not a regular file (a device, pipe or directory)')
        with path.open('rb') as stream:
            data = stream.read(MAX_BYTES + 1)  # at most: a file may grow after the check
    except OSError as exc:
        raise ConfigError(f'{path}: cannot read ({exc.strerror or exc})') from None
    if len(data) > MAX_BYTES:
        raise ConfigError(f'{path}: larger than {MAX_BYTES >> 20} MiB: not a configuration '
                          'file')
    try:
        text = data.decode('utf-8')
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


def key_name(key: Any) -> str | None:
    """A mapping key as an error message may show it: a name (up to 64 letters, digits and
    ``_./*~-``) as it is, a short number, boolean or null as repr; None for anything else (a
    file that is not a configuration file, /etc/shadow say, has its lines as keys: never
    echoed)."""
    if isinstance(key, str):
        return key if _NAME.fullmatch(key) else None
    if key is None or isinstance(key, bool) or \
            (isinstance(key, (int, float)) and abs(key) < 1e15):
        return repr(key)
    return None


def key_list(keys: Iterable[Any]) -> str:
    """Mapping keys for a one-line message: the ``key_name`` ones sorted, comma-separated; the
    others counted."""
    shown = [key_name(k) for k in keys]
    names = sorted(n for n in shown if n is not None)
    others = len(shown) - len(names)
    if others:
        names.append(f'{others} more key{"s" if others > 1 else ""} that '
                     f'{"are" if others > 1 else "is"} not a name')
    return ', '.join(names)


#: Parameters every ROS 2 node declares itself; a params file may set them for any node.
ROS_BUILTIN_PARAMETERS = frozenset({'use_sim_time'})


def ros_parameters(doc: Any, node_name: str, known: Collection[str] | None = None,
                   source: str = 'parameters', *, refused: Mapping[str, str] | None = None,
                   shared_known: Collection[str] | None = None, required: bool = True,
                   namespace: str | None = None) -> dict[str, Any]:
    """The parameters a ROS params file gives node ``node_name``; strict, one-line errors.

    Sections that apply (ROS semantics, merged in file order): ``node_name``, ``/node_name``,
    ``/<namespace>/node_name``, ``/**/node_name`` and ``/**``; other sections configure other
    nodes and are skipped. With ``namespace`` (a node started in it, ``/`` for the root) the
    sections are matched as rcl does (``section_applies``).
    Each section must be ``{ros__parameters: {...}}``. ConfigError naming ``source`` when the
    file is not such a mapping, when no section applies (``required``; else ``{}``), for a key
    in ``refused`` (its message says what to do instead) and, when ``known`` is given, for a key
    outside ``known`` (with the closest known name). Keys of ``/**`` (a file shared by several
    nodes) are checked against ``shared_known`` instead when given (every node's names: a key
    for another node is skipped, a typo is an error). ``use_sim_time`` is accepted and dropped.
    """
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(f'{source}: expected a ROS params file ({node_name}: ros__parameters: '
                          '...)')
    params: dict[str, Any] = {}
    shared: set[str] = set()  # names set only by /** sections
    found = False
    for key, section in doc.items():
        if not section_applies(key, node_name, namespace):
            continue
        if not isinstance(section, dict) or set(section) != {'ros__parameters'} or \
                not isinstance(section['ros__parameters'], (dict, type(None))):
            raise ConfigError(f'{source}: section {key}: expected only "ros__parameters:" with '
                              'a mapping of parameters')
        found = True
        values = _names(section['ros__parameters'] or {}, source, key)
        params.update(values)
        shared = shared | set(values) if key == '/**' else shared - set(values)
    if not found:
        if not required:
            return {}
        present = f' (sections: {key_list(doc)})' if doc else ' (the file is empty)'
        raise ConfigError(f'{source}: no section for node {node_name} ("{node_name}:" or '
                          f'"/**:" with ros__parameters:){present}')
    for key in params:
        if refused is not None and key in refused:
            raise ConfigError(f'{source}: {node_name}: {key}: {refused[key]}')
    if known is not None:
        allowed = set(known) | ROS_BUILTIN_PARAMETERS
        wide = allowed if shared_known is None else allowed | set(shared_known)
        unknown = {k for k in params if k not in (wide if k in shared else allowed)}
        if unknown:
            close = [m for k in sorted(unknown) for m in get_close_matches(k, known, 1, 0.75)]
            hint = f' (did you mean {", ".join(close)}?)' if close else ''
            raise ConfigError(f'{source}: {node_name}: unknown parameter(s) '
                              f'{key_list(unknown)}{hint}')
    return {k: v for k, v in params.items()
            if k not in ROS_BUILTIN_PARAMETERS and (known is None or k in known)}


def section_applies(key: Any, node_name: str, namespace: str | None = None) -> bool:
    """Whether params-file section ``key`` configures node ``node_name``: any section naming it
    (``/<anything>/node_name``) or ``/**``; with ``namespace``, as rcl matches the fully
    qualified name ``<namespace>/<node_name>`` (a key without a leading ``/`` is in the root
    namespace, ``*`` is one name, ``**`` any number of them)."""
    if not isinstance(key, str):
        return False
    if namespace is not None:
        pattern = ''.join('(/[^/]+)*' if part == '**' else '/[^/]+' if part == '*'
                          else '/' + re.escape(part) for part in key.strip('/').split('/'))
        return re.fullmatch(pattern, f'{namespace.rstrip("/")}/{node_name}') is not None
    return key in (node_name, '/**') or (key.startswith('/') and key.rsplit('/', 1)[-1] == \
        node_name)


def _names(params: dict, source: str, section: str) -> dict[str, Any]:
    """``params`` whose keys are all names (printable non-empty strings), else ConfigError."""
    for key in params:
        if not isinstance(key, str) or not key.isprintable() or not key:
            raise ConfigError(f'{source}: section {section}: parameter name '
                              f'{key_name(key) or "(not shown)"} is not a name')
    return params


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
