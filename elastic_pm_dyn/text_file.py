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


def read_text(path: str | Path, max_bytes: int, what: str = "file") -> str:
    """The UTF-8 text of ``path`` (a byte-order mark dropped); TextFileError if it cannot be
    read, is larger than ``max_bytes`` or is not UTF-8."""
    p = Path(path)
    try:
        # Opened without blocking (a FIFO without a writer would block open()), then checked.
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
        with os.fdopen(fd, "rb") as fh:
            info = os.fstat(fd)
            if not stat.S_ISREG(info.st_mode):
                raise TextFileError(f"not a regular file ({_kind(info.st_mode)}); give a file")
            size = info.st_size
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
