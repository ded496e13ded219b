"""Safe output: never onto an input, atomic (a temporary sibling renamed into place only when
everything worked), and writable directories checked before the work starts."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
import os
from pathlib import Path
import shutil
import tempfile

from railgsa_ros.errors import ConfigError


def refuse_overlap(output: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """ConfigError when ``output`` is an input, lies inside an input (a bag directory) or
    contains one (a directory that writing, or ``--overwrite``, would replace), whether or not
    either exists yet. Paths are compared resolved (symlinks, ``..``, relative paths)."""
    out = Path(os.path.realpath(output))
    for given in inputs:
        if given is None or str(given) == '':
            continue
        source = Path(os.path.realpath(given))
        if out == source or source in out.parents or out in source.parents:
            relation = 'is' if out == source else 'is inside' if source in out.parents \
                else 'contains'
            raise ConfigError(f'{output}: the output {relation} the input {given} (choose '
                              'another output path)')


def writable_dir(path: str | Path) -> Path:
    """Create directory ``path`` if needed and check that files can be created in it (a
    read-only file system, missing permissions); ConfigError naming it otherwise."""
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write ({exc.strerror or exc})') from None
    return path


@contextmanager
def atomic_output(path: str | Path, overwrite: bool = False) -> Iterator[Path]:
    """Yield a not-yet-existing temporary path; on success it is renamed to ``path``.

    The temporary path lies in a hidden directory next to ``path`` (same file system, so the
    rename is atomic) and may become a file or a directory. On any exception nothing is left
    behind and an existing ``path`` is untouched. An existing ``path`` is an error unless
    ``overwrite`` is true. Unwritable locations and OSErrors inside the block (disk full) raise
    ConfigError naming ``path``.
    """
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise ConfigError(f'{path}: already exists (choose another output path)')
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        holder = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.tmp', dir=parent))
    except OSError as exc:
        raise ConfigError(f'{path}: cannot write ({exc.strerror or exc})') from None
    try:
        tmp = holder / path.name
        yield tmp
        if not (tmp.exists() or tmp.is_symlink()):
            raise ConfigError(f'{path}: nothing was written')
        _commit(tmp, path, holder)
    except OSError as exc:  # e.g. disk full while writing
        raise ConfigError(f'{path}: cannot write ({exc.strerror or exc})') from None
    finally:
        shutil.rmtree(holder, ignore_errors=True)


def _commit(tmp: Path, path: Path, holder: Path) -> None:
    """Move ``tmp`` to ``path``; an existing ``path`` is swapped out first, then deleted."""
    old = holder / (path.name + '.old')
    try:
        if path.exists() or path.is_symlink():
            os.replace(path, old)
        os.replace(tmp, path)
    except OSError as exc:
        if old.exists() or old.is_symlink():
            os.replace(old, path)
        raise ConfigError(f'{path}: cannot write ({exc.strerror or exc})') from None
