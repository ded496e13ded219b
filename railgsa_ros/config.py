"""Reading YAML configuration files with one-line errors that name the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from railgsa_ros.errors import ConfigError


def load_yaml(path: str | Path) -> Any:
    """Parse a YAML file; missing, unreadable or malformed files raise ConfigError naming it."""
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


def ros_parameters(doc: Any, node_name: str) -> dict[str, Any]:
    """Return ``doc[node_name]['ros__parameters']`` (or ``/**``), the ROS params-file layout."""
    if not isinstance(doc, dict):
        return {}
    for key in (node_name, f'/{node_name}', '/**'):
        section = doc.get(key)
        if isinstance(section, dict) and isinstance(section.get('ros__parameters'), dict):
            return section['ros__parameters']
    return {}
