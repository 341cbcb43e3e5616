"""Output files written whole or not at all, and the checks a path passes before any work.

Every file the package writes goes to a temporary file beside it, is flushed to disk and renamed
over the path (``os.replace``, atomic within a directory): a full disk, a file-size limit or an
interrupt leaves the old file or none, never a truncated one. Through a symbolic link the link's
target is replaced and the link kept. The command line checks each path before the run
(:func:`output_problem`, :func:`same_file`) without opening it: opening a FIFO blocks, and
opening a device writes to it.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import stat
from collections.abc import Callable
from pathlib import Path

# What a path that is neither a regular file nor a new one is, in the words of the refusal.
KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
         (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


class Output(os.PathLike):
    """A path the command line writes, with the flag that named it. Written through this
    module, a failure is kept in ``error`` instead of raised, so that a run goes on to its other
    outputs and the command line reports each failure in one line, also where the write happens
    deep inside a run (the replay, written by ``closed_loop.simulate``)."""

    def __init__(self, path: str, flag: str) -> None:
        self.path, self.flag = path, flag
        self.error: OSError | None = None

    def __fspath__(self) -> str:
        return self.path

    def __str__(self) -> str:
        return self.path


def json_text(data) -> str:
    """``data`` as JSON that every parser reads (RFC 8259 has no NaN or Infinity): a number
    that is not finite (a gap without a bound, a cost without a plan) is null."""
    def finite(x):
        if isinstance(x, float) and not math.isfinite(x):
            return None
        if isinstance(x, dict):
            return {k: finite(v) for k, v in x.items()}
        if isinstance(x, list | tuple):
            return [finite(v) for v in x]
        return x

    return json.dumps(finite(data), indent=1, allow_nan=False)


def write(path: str | Path | Output, data: str | bytes) -> None:
    """Write ``data`` (text as UTF-8) to ``path`` whole or not at all."""
    write_with(path, lambda tmp: tmp.write_bytes(data.encode() if isinstance(data, str)
                                                 else data))


def write_with(path: str | Path | Output, writer: Callable[[Path], None],
               suffix: str = ".tmp") -> None:
    """Let ``writer`` write a new temporary path beside ``path`` (named with ``suffix``, for
    writers that go by the extension), then rename it over ``path``; if anything raises, the
    temporary file is removed. An ``OSError`` names ``path``, not the temporary file; for an
    :class:`Output` it is kept in its ``error``."""
    try:
        target = Path(os.path.realpath(path))
        tmp = _beside(target, suffix)
        try:
            writer(tmp)
            _sync(tmp)
            os.replace(tmp, target)
            _sync(target.parent)  # the rename itself survives a crash
        finally:
            tmp.unlink(missing_ok=True)
    except OSError as err:
        named = OSError(err.errno, err.strerror, os.fspath(path))
        if not isinstance(path, Output):
            raise named from None
        path.error = named


def _beside(target: Path, suffix: str) -> Path:
    """A new empty file in ``target``'s directory, with ``target``'s mode if it exists (else
    0o666 less the umask, as open() makes it)."""
    # within the 255 bytes of a file name, whatever the target's length
    tmp = target.with_name(f".{target.name[:64]}.{secrets.token_hex(6)}{suffix}")
    os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
    try:
        if target.is_file():
            os.chmod(tmp, stat.S_IMODE(target.stat().st_mode))
    except OSError:
        tmp.unlink()
        raise
    return tmp


def _sync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def output_problem(path: str) -> str | None:
    """Why the run could not write ``path`` at its end, or None: the path must be a regular
    file or a new one, in a directory that exists and takes new files (tried with a temporary
    file there, as the write will be; the path itself is never opened)."""
    if not path:
        return "an empty path"
    if path.endswith(os.sep) or os.path.basename(path) in (".", ".."):
        return f"{path} names a directory"
    written = os.path.dirname(path) or "."
    if not os.path.isdir(written):  # judged as the OS will: x/../p.json needs x
        return f"directory {_first_missing(written)} does not exist"
    try:
        mode = os.stat(path).st_mode  # through symbolic links
    except FileNotFoundError:
        mode = None
    except OSError as err:  # a loop of symbolic links, a file used as a directory, ...
        return f"{path}: {err.strerror}"
    if mode is not None and stat.S_ISDIR(mode):
        return f"{path} is a directory"
    if mode is not None and not stat.S_ISREG(mode):
        kind = next((name for test, name in KINDS if test(mode)), "a special file")
        return f"{path} is {kind}, not a regular file"
    if mode is not None and not os.access(path, os.W_OK):
        return f"cannot write {path}: it is read-only"
    target = Path(os.path.realpath(path))
    if not target.parent.is_dir():  # a symbolic link to nothing, in a directory not there
        return (f"{path} is a symbolic link to {os.readlink(path)}, and directory "
                f"{_first_missing(str(target.parent))} does not exist")
    reason = _cannot_create_in(target)
    return f"cannot write {path}: {reason}" if reason else None


def _first_missing(directory: str) -> str:
    """The first directory on the way to ``directory`` that does not exist (as written)."""
    parts = Path(directory).parts
    for k in range(1, len(parts) + 1):
        prefix = os.path.join(*parts[:k])
        if not os.path.isdir(prefix):
            return prefix
    return directory


def directory_problem(path: str) -> str | None:
    """Why the run could not write files into directory ``path`` (made if it is missing, in a
    directory that exists), or None."""
    if not path:
        return "an empty path"
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        return f"{path}: {err.strerror}"
    if mode is not None and not stat.S_ISDIR(mode):
        return f"{path} is not a directory"
    if mode is None and os.path.islink(path):
        return f"{path} is a symbolic link to nothing"
    p = Path(os.path.realpath(path))
    where = p if mode is not None else p.parent
    if not where.is_dir():
        return f"directory {os.path.dirname(os.path.normpath(path)) or '.'} does not exist"
    reason = _cannot_create_in(where / ".probe")
    return f"cannot write in {path}: {reason}" if reason else None


def _cannot_create_in(target: Path) -> str | None:
    """Why no temporary file can be made beside ``target`` (the OS's reason), or None."""
    try:
        _beside(target, ".tmp").unlink()
    except OSError as err:
        return err.strerror
    return None


def same_file(a: str | Path, b: str | Path) -> bool:
    """Whether ``a`` and ``b`` name one file: the same path once symbolic links and ``..`` are
    resolved, or hard links to one inode."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist yet
        return False
