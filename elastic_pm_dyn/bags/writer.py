"""Write a rosbag2 bag (mcap or sqlite3) with the message definitions stored: the one writer.

Messages go in as raw CDR (the recorder's wire bytes, our own encoders' output), as
rosbags message objects (serialised with the writer's typestore), or as rows of a batch:
row k's message of every connection, row after row (:meth:`BagWriter.write_rows`, the
estimates bag's fast path). Either way the bag is what ``ros2 bag`` and rosbags read.

A writer killed at any moment leaves a bag that :func:`~elastic_pm_dyn.bags.reader.open_bag`
reads up to the last flush: ``metadata.yaml`` exists from the start, marked unfinished
(:mod:`~elastic_pm_dyn.bags.metadata`); an mcap chunk carries its CRC, so a reader can tell
a complete chunk from a torn one; sqlite3 rows go in by transactions that commit at each
flush. With ``flush_period`` (the recorder's) a flush happens at least that often in
wall-clock time while messages come in, and :meth:`BagWriter.flush` forces one.
"""

from __future__ import annotations

import time
from binascii import crc32
from collections import defaultdict
from collections.abc import Sequence
from io import BytesIO
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionMode
from rosbags.rosbag2.storage_mcap import (
    McapWriter,
    PendingChunk,
    write_record,
    write_string,
    write_uint16,
    write_uint32,
    write_uint64,
)
from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer
from rosbags.typesys.store import Typestore

from elastic_pm_dyn.bags.errors import WRITE_ERRORS, BagError, one_line
from elastic_pm_dyn.bags.metadata import write_unfinished
from elastic_pm_dyn.bags.typestore import make_typestore

_PLUGINS = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
STORAGES = tuple(_PLUGINS)
SQLITE_BATCH = 5000  # sqlite3 rows held before they are inserted and committed (without flush_period too)
_INSERT = "INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)"


class BagWriter:
    """A new bag at ``path`` (never overwritten), open until :meth:`close` (or the end of a
    ``with`` block; an exception there aborts it instead). ``typestore`` gives the
    definitions stored for each connection (default: :func:`make_typestore`).
    ``flush_period`` [s]: flush at least this often while writing (None: only when an mcap
    chunk is full, every :data:`SQLITE_BATCH` sqlite3 rows, and at :meth:`flush`)."""

    def __init__(self, path: str | Path, storage: str = "mcap", typestore: Typestore | None = None,
                 flush_period: float | None = None):
        self.path = Path(path)
        if storage not in _PLUGINS:
            raise BagError(f"{self.path}: unknown storage {storage!r} (expected {' or '.join(STORAGES)})")
        if self.path.exists():
            raise BagError(f"{self.path} exists already (a bag is never overwritten)")
        self.typestore = typestore if typestore is not None else make_typestore()
        self._w = Writer(self.path, version=Writer.VERSION_LATEST, storage_plugin=_PLUGINS[storage])
        self.flush_period = flush_period
        self._last_flush = time.monotonic()
        self._rows: list[tuple[int, int, bytes | memoryview]] = []  # sqlite3 rows not yet inserted
        self._durable: dict[int, int] = {}  # connection id -> messages flushed to the file
        try:
            self._w.open()
            if isinstance(self._w.storage, McapWriter):
                # rosbags writes CRC 0 ("none"); ours lets a reader reject a torn or damaged chunk.
                st = self._w.storage
                st.close_chunk = lambda: _close_chunk_with_crc(st)
                st.bio.flush()  # magic and header in the file: a kill before any chunk leaves an mcap, if empty
            else:
                self._w.storage.conn.commit()  # the tables, before any message
            write_unfinished(self._w)
        except WRITE_ERRORS as err:
            raise BagError(f"{self.path}: cannot create the bag: {_reason(err)}") from None

    def add_connection(self, topic: str, msgtype: str) -> Any:
        """A connection (rosbags ``Connection``) for ``topic``, its definition from the typestore."""
        try:
            conn = self._w.add_connection(topic, msgtype, typestore=self.typestore)
            if isinstance(self._w.storage, Sqlite3Writer):
                self._w.storage.conn.commit()  # the topic is in the file before its first message
            write_unfinished(self._w)
        except (*WRITE_ERRORS, KeyError) as err:  # KeyError: a type the typestore does not know
            raise BagError(f"{self.path}: cannot record {topic} [{msgtype}]: {one_line(err)}") from None
        self._durable[conn.id] = 0
        return conn

    def write(self, conn: Any, t_ns: int, raw: bytes | memoryview) -> bool:
        """One message as raw CDR, received at ``t_ns`` [ns]; True if the bag was flushed with it."""
        if isinstance(self._w.storage, Sqlite3Writer):
            w = self._w
            self._rows.append((conn.id, t_ns, raw))
            w.counts[conn.id] += 1
            w.min_timestamp = min(t_ns, w.min_timestamp)
            w.max_timestamp = max(t_ns, w.max_timestamp)
            if len(self._rows) >= SQLITE_BATCH:
                return self.flush()
        else:
            self._w.write(conn, t_ns, raw)
        return self._flush_if_due()

    def write_message(self, conn: Any, t_ns: int, msg: Any) -> bool:
        """One rosbags message object, serialised with the writer's typestore."""
        return self.write(conn, t_ns, self.typestore.serialize_cdr(msg, conn.msgtype))

    def flush(self) -> bool:
        """Put every message written so far into the file, complete (an mcap chunk, a sqlite3
        commit): what a reader gets back if this process is killed now. True if there was any."""
        st = self._w.storage
        self._last_flush = time.monotonic()
        if st is None:
            return False
        try:
            if isinstance(st, McapWriter):
                if not st.chunk.bio.tell():
                    return False
                st.close_chunk()
                st.bio.flush()
            else:
                if not self._rows:
                    return False
                st.cursor.executemany(_INSERT, self._rows)
                st.conn.commit()
                self._rows.clear()
        except WRITE_ERRORS as err:
            raise BagError(f"{self.path}: cannot write to the bag: {_reason(err)}") from None
        self._durable = {cid: self._w.counts[cid] for cid in self._durable}
        return True

    def durable(self, conn: Any) -> int:
        """Messages of ``conn`` in the file as of the last flush (they survive a kill)."""
        return self._durable.get(conn.id, 0)

    def _flush_if_due(self) -> bool:
        if self.flush_period is not None and time.monotonic() - self._last_flush >= self.flush_period:
            return self.flush()
        return False

    def write_rows(self, conns: Sequence[Any], ns: np.ndarray, msgs: Sequence[np.ndarray]) -> None:
        """Row k's message of every connection (``msgs[c][k]``: its raw CDR, rows x bytes as
        ``cdr.encode_*_batch`` give them), stamped ``ns[k]``, row after row: the bag
        :meth:`write` would give, several times faster on mcap."""
        if _write_rows_mcap(self._w, conns, ns, msgs):
            self._flush_if_due()
            return
        write = self.write
        blobs = [(m.tobytes(), m.shape[1]) for m in msgs]
        for k, t in enumerate(ns.tolist()):
            for c, (blob, size) in zip(conns, blobs, strict=True):
                write(c, t, blob[k * size:(k + 1) * size])

    def count(self, conn: Any) -> int:
        """Messages written on ``conn`` so far."""
        return self._w.counts[conn.id]

    def set_custom_data(self, key: str, value: str) -> None:
        """A ``custom_data`` entry of the finished bag's metadata.yaml (e.g. what a recorder lost)."""
        self._w.set_custom_data(key, value)

    def close(self) -> None:
        """Finish the bag (index, metadata.yaml)."""
        if self._w.storage is not None:
            if self._rows:
                self.flush()
            try:
                self._w.close()
            except WRITE_ERRORS as err:
                raise BagError(f"{self.path}: cannot finish the bag: {_reason(err)}") from None

    def abort(self) -> None:
        """Stop writing without finishing the bag (it stays marked unfinished, readable up to the last flush)."""
        self._w.abort()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _reason(err: BaseException) -> str:
    return err.strerror if isinstance(err, OSError) and err.strerror else one_line(err)


def _close_chunk_with_crc(st: McapWriter) -> None:
    """rosbags' ``McapWriter.close_chunk`` with the chunk's CRC-32 written (mcap: 0 means none)."""
    chunk = st.chunk
    data = chunk.bio.getvalue()
    rec = BytesIO()
    write_uint64(rec, chunk.message_start_time)
    write_uint64(rec, chunk.message_end_time)
    write_uint64(rec, len(data))
    write_uint32(rec, crc32(data))
    compressed = st.compressor(data)
    write_string(rec, st.compression)
    write_uint64(rec, len(compressed))
    rec.write(compressed)
    chunk_start = st.bio.tell()
    write_record(st.bio, 0x06, rec)
    chunk_end = st.bio.tell()
    offsets: list[tuple[int, int]] = []
    for cid, msgs in chunk.msgs.items():
        offsets.append((cid, st.bio.tell()))
        rec = BytesIO()
        write_uint16(rec, cid)
        write_uint32(rec, len(msgs) * 16)
        for ts, offset in msgs:
            write_uint64(rec, ts)
            write_uint64(rec, offset)
        write_record(st.bio, 0x07, rec)
    rec = BytesIO()  # the chunk index, for the summary written at close
    write_uint64(rec, chunk.message_start_time)
    write_uint64(rec, chunk.message_end_time)
    write_uint64(rec, chunk_start)
    write_uint64(rec, chunk_end - chunk_start)
    write_uint32(rec, len(offsets) * 10)
    for cid, offset in offsets:
        write_uint16(rec, cid)
        write_uint64(rec, offset)
    write_uint64(rec, st.bio.tell() - chunk_end)
    write_string(rec, st.compression)
    write_uint64(rec, len(compressed))
    write_uint64(rec, len(data))
    st.chunks.append(rec)
    st.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))


def _write_rows_mcap(w: Writer, conns: Sequence[Any], ns: np.ndarray, msgs: Sequence[np.ndarray]) -> bool:
    """Write row k's message of every connection, row after row, as ``Writer.write`` would,
    but with the mcap message records built at once with numpy (rosbags spent ~10 us per
    message on them, measured 2026-11-22 on the 2-core dev machine). Only for rosbags'
    uncompressed ``McapWriter`` as we know it (False
    otherwise: the caller writes message by message); the file is byte for byte the same."""
    st = w.storage
    chunk = getattr(st, "chunk", None)
    if (type(st) is not McapWriter or w.compression_mode != CompressionMode.NONE or st.compression != ""
            or not isinstance(getattr(chunk, "bio", None), BytesIO) or not isinstance(chunk.msgs, defaultdict)
            or not all(c.id in st.channel_stats for c in conns)):
        return False
    n = len(ns)
    # Record: op 0x05, u64 length, u16 channel id, u32 sequence 0, u64 log time, u64 publish time, data.
    parts, sizes = [], []
    stamp = ns.astype("<u8").view(np.uint8).reshape(n, 8)
    for c, m in zip(conns, msgs, strict=True):
        rec = np.zeros((n, 31 + m.shape[1]), dtype=np.uint8)
        rec[:, 0] = 0x05
        rec[:, 1:9] = np.frombuffer(int(22 + m.shape[1]).to_bytes(8, "little"), dtype=np.uint8)
        rec[:, 9:11] = np.frombuffer(int(c.id).to_bytes(2, "little"), dtype=np.uint8)
        rec[:, 15:23] = stamp
        rec[:, 23:31] = stamp
        rec[:, 31:] = m
        parts.append(rec)
        sizes.append(rec.shape[1])
    blob = np.hstack(parts).tobytes() if n else b""
    t = ns.tolist()
    ids = [c.id for c in conns]
    counts = dict.fromkeys(ids, 0)
    limit = 2**20  # McapWriter closes a chunk after the message that takes it past 1 MiB
    chunk = st.chunk
    pos = chunk.bio.tell()
    seg, first = 0, 0  # blob offset and row where the pending segment starts
    end = 0

    def flush(last_row: int) -> None:
        chunk.bio.write(blob[seg:end])
        lo, hi = min(t[first:last_row + 1]), max(t[first:last_row + 1])
        chunk.message_start_time = min(lo, chunk.message_start_time)
        chunk.message_end_time = max(hi, chunk.message_end_time)
        st.message_start_time = min(lo, st.message_start_time)
        st.message_end_time = max(hi, st.message_end_time)
        w.min_timestamp = min(lo, w.min_timestamp)
        w.max_timestamp = max(hi, w.max_timestamp)

    last = len(ids) - 1
    for r in range(n):
        tr = t[r]
        for j, (cid, size) in enumerate(zip(ids, sizes, strict=True)):
            chunk.msgs[cid].append((tr, pos))
            counts[cid] += 1
            pos += size
            end += size
            if pos > limit:
                flush(r)
                st.close_chunk()
                chunk = st.chunk
                pos = chunk.bio.tell()
                # The next chunk starts with the rest of row r, or with row r + 1 after its last message.
                seg, first = end, r + 1 if j == last else r
    if end > seg:
        flush(n - 1)
    for cid, cnt in counts.items():
        st.channel_stats[cid] += cnt
        w.counts[cid] += cnt
    return True
