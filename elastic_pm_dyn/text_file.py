"""Reading a user's text file (model, parameters, torque table) safely: one job, one place.

Only regular files are read (a device such as /dev/zero or a FIFO would never end, or
block), the size is checked before anything is read (a file of gigabytes is refused at
once) and no more than the limit is read even if the file grows meanwhile; bytes that are
not UTF-8 are reported with their line, so every reader of user files gives the same
one-line errors.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO


class TextFileError(Exception):
    """Why a file could not be read as text; ``line`` where known. Readers turn it into
    their own error (ModelError, InputError) with their own wording around ``reason``."""

    def __init__(self, reason: str, line: int | None = None):
        self.reason, self.line = reason, line
        super().__init__(reason)


def _size(n: int) -> str:
    return f"{n / 2**20:.3g} MiB" if n >= 2**20 else f"{n / 1024:.3g} kiB"


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a file"


def _open_regular(p: Path) -> tuple[BinaryIO, int]:
    """(binary file object, size) of a regular file, opened without blocking (a FIFO without a
    writer would block open()); TextFileError for anything else."""
    fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):  # (checked before fdopen, which refuses a directory itself)
            raise TextFileError(f"not a regular file ({_kind(info.st_mode)}); give a file")
        fh = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    return fh, info.st_size


def read_text(path: str | Path, max_bytes: int, what: str = "file") -> str:
    """The UTF-8 text of ``path`` (a byte-order mark dropped); TextFileError if it cannot be
    read, is larger than ``max_bytes`` or is not UTF-8."""
    p = Path(path)
    try:
        fh, size = _open_regular(p)
        with fh:
            if size > max_bytes:
                raise TextFileError(f"{_size(size)} ({size} bytes), more than the {_size(max_bytes)} "
                                    f"a {what} may have")
            raw = fh.read(max_bytes + 1)
        if len(raw) > max_bytes:  # it grew while we read
            raise TextFileError(f"more than the {_size(max_bytes)} a {what} may have")
    except OSError as exc:
        raise TextFileError(f"cannot read file: {exc.strerror or exc}") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise TextFileError(f"not UTF-8 text: byte 0x{raw[exc.start]:02x} at byte {exc.start}",
                            raw.count(b"\n", 0, exc.start) + 1) from None


def read_head(path: str | Path, n_bytes: int) -> bytes:
    """The first ``n_bytes`` of a regular file (to tell its format), with the same refusals as
    :func:`read_text` (a FIFO, a device, a directory: TextFileError at once, never a block)."""
    try:
        fh, _ = _open_regular(Path(path))
        with fh:
            return fh.read(n_bytes)
    except OSError as exc:
        raise TextFileError(f"cannot read file: {exc.strerror or exc}") from None
