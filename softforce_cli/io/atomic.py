"""Atomic, non-clobbering file output: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from softforce_cli.errors import OutputExistsError


def new_file_mode() -> int:
    """0o666 less the process umask: what open() would give, unlike mkstemp's 0o600."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def check_writable(path: Path, force: bool) -> None:
    """Raise OutputExistsError if `path` exists and `force` is not set."""
    if path.exists() and not force:
        raise OutputExistsError(f"{path} already exists; pass --force to overwrite it")


@contextlib.contextmanager
def atomic_open(path: Path, mode: str = "w", force: bool = False) -> Iterator[IO]:
    """Open a temporary file next to `path`; on success rename it over `path`, else delete it.

    A reader never sees a half-written `path`, and an existing file survives a failure.
    """
    path = Path(path)
    check_writable(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, mode) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_path(path: Path, force: bool = False) -> Iterator[Path]:
    """A temporary path next to `path` for writers that want a file name (meshio, mcap...);
    renamed over `path` on success, deleted on failure. Keeps the suffix for format sniffing."""
    path = Path(path)
    check_writable(path, force)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str, force: bool = False) -> None:
    with atomic_open(path, "w", force=force) as handle:
        handle.write(text)


def atomic_write_bytes(path: Path, data: bytes, force: bool = False) -> None:
    with atomic_open(path, "wb", force=force) as handle:
        handle.write(data)
