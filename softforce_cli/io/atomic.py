"""Atomic, non-clobbering file output: write to a temporary file beside the target, then rename."""

from __future__ import annotations

import contextlib
import os
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from softforce_cli.errors import OutputError, OutputExistsError


def new_file_mode() -> int:
    """0o666 less the process umask: what open() would give, unlike mkstemp's 0o600."""
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


def check_writable(path: Path, force: bool) -> None:
    """Raise OutputExistsError if `path` exists and `force` is not set."""
    if path.exists() and not force:
        raise OutputExistsError(f"{path} already exists; pass --force to overwrite it")


def writable_folder(folder: Path) -> Path:
    """`folder`, made with its parents when missing; OutputError (one line) when it cannot
    be (a read-only or virtual file system, a file in the way)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputError(f"cannot write in {folder}: {error.strerror or error}") from error
    return folder


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM back within the block, and raise them at its end: a Ctrl-C then
    arrives once a file is complete (or once it is ours to delete) instead of leaving it
    half-finished (or behind).

    Python runs signal handlers in the main thread whichever thread the signal reached, so
    the handlers are swapped for ones that only note the signal, and the noted signals are
    raised again, to the original handlers, at the end.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    noted: list[int] = []
    kinds = (signal.SIGINT, signal.SIGTERM)
    previous = {kind: signal.signal(kind, lambda signum, _: noted.append(signum)) for kind in kinds}
    try:
        yield
    finally:
        for kind, handler in previous.items():
            signal.signal(kind, handler)
        for signum in dict.fromkeys(noted):
            signal.raise_signal(signum)


def temporary_beside(path: Path, prefix: str, suffix: str) -> tuple[int, Path]:
    """(descriptor, path) of a new temporary file in `path`'s folder (made when missing), or
    OutputError naming `path` when no file can be made there."""
    writable_folder(path.parent)
    try:
        fd, name = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=path.parent)
    except OSError as error:
        raise OutputError(f"cannot write {path}: {error.strerror or error}") from error
    return fd, Path(name)


def check_can_write(path: Path) -> None:
    """OutputError now, not after the work, when no file can be written beside `path`.

    The folders made for the probe are removed again, so that a run refused later on (bad
    input found mid-way) leaves no empty output folder behind."""
    path = Path(path)
    missing = [folder for folder in path.parents if not folder.exists()]
    with signals_held():  # a Ctrl-C between making the probe and removing it leaves none
        fd, tmp = temporary_beside(path, f".{path.name}.", ".probe")
        os.close(fd)
        tmp.unlink()
    for folder in missing:  # deepest first
        with contextlib.suppress(OSError):
            folder.rmdir()


@contextlib.contextmanager
def atomic_open(path: Path, mode: str = "w", force: bool = False) -> Iterator[IO]:
    """Open a temporary file next to `path`; on success rename it over `path`, else delete it.

    A reader never sees a half-written `path`, and an existing file survives a failure.
    """
    path = Path(path)
    check_writable(path, force)
    tmp: Path | None = None
    try:
        with signals_held():  # a Ctrl-C as the file is made arrives once it is ours to delete
            fd, tmp = temporary_beside(path, f".{path.name}.", ".tmp")
            handle = os.fdopen(fd, mode)
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_path(path: Path, force: bool = False) -> Iterator[Path]:
    """A temporary path next to `path` for writers that want a file name (meshio, mcap...);
    renamed over `path` on success, deleted on failure. Keeps the suffix for format sniffing."""
    path = Path(path)
    check_writable(path, force)
    tmp: Path | None = None
    try:
        with signals_held():  # a Ctrl-C as the file is made arrives once it is ours to delete
            fd, tmp = temporary_beside(path, f".{path.stem}.", f".tmp{path.suffix}")
            os.close(fd)
        yield tmp
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str, force: bool = False) -> None:
    with atomic_open(path, "w", force=force) as handle:
        handle.write(text)


def atomic_write_bytes(path: Path, data: bytes, force: bool = False) -> None:
    with atomic_open(path, "wb", force=force) as handle:
        handle.write(data)
