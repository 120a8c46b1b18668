"""One error for every way a bag can fail, with a one-line message naming the bag."""

from __future__ import annotations

import sqlite3
import struct

import apsw
from rosbags.highlevel import AnyReaderError
from rosbags.rosbag2 import ReaderError, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import TypesysError

from elastic_pm_dyn.errors import InputError


class BagError(InputError):
    """A bag that cannot be read or written: missing, not a bag, truncated or corrupt, undecodable."""


# What rosbags and broken storage files raise while reading (garbage sizes, offsets, strings;
# TypeError: rosbags' mcap reader takes ord() of a read that hit the end of the file; apsw:
# the sqlite3 reader's own errors, e.g. a malformed page met while reading messages).
READ_ERRORS: tuple[type[BaseException], ...] = (
    AnyReaderError, ReaderError, SerdeError, TypesysError, sqlite3.DatabaseError, apsw.Error, struct.error,
    EOFError, ValueError, KeyError, IndexError, UnicodeDecodeError, OverflowError, MemoryError, AssertionError,
    TypeError)
# What rosbags raises while writing (an existing bag, an unknown type, a full disk).
WRITE_ERRORS: tuple[type[BaseException], ...] = (WriterError, TypesysError, SerdeError, OSError, sqlite3.Error)


def one_line(err: BaseException) -> str:
    """The text of ``err`` on one line of at most 300 characters (its type if it has none)."""
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 300 else text[:297] + "..."
