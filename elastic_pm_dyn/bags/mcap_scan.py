"""Read an mcap file that has no footer: the complete records from its start, up to the first bad one.

A writer killed mid-recording leaves an mcap without summary and footer, which rosbags
(and most readers) refuse: they start from the footer. The data section is still a plain
sequence of records (opcode u8, length u64, content), and rosbags writes schemas and
channels into the chunks with the messages. :func:`scan_mcap` walks that sequence from
the header, keeps every chunk that is complete, decompresses and whose CRC (when written)
matches, and stops at the first record that is cut off or does not parse. The
:class:`McapScan` it returns has rosbags ``Connection`` s and yields the messages of the
kept chunks as rosbags' reader does (by receive time, chunks merged).
"""

from __future__ import annotations

import heapq
import mmap
import struct
from binascii import crc32
from collections import defaultdict
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, MessageDefinition, MessageDefinitionFormat
from rosbags.rosbag2.metadata import parse_qos

MAGIC = b"\x89MCAP0\r\n"
FOOTER_SIZE = 29  # op, length, summary start, summary offset start, summary CRC (then the magic)
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_CHUNK_HEAD = struct.Struct("<QQQI")  # message start time, end time, uncompressed size, CRC
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_FORMATS = {"ros2msg": MessageDefinitionFormat.MSG, "ros2idl": MessageDefinitionFormat.IDL}


class McapScanError(Exception):
    """The file is not an mcap, or not even its header is complete."""


def has_footer(path: Path) -> bool:
    """True if the file ends with an mcap footer record and the closing magic."""
    try:
        with path.open("rb") as fh:
            size = fh.seek(0, 2)
            if size < len(MAGIC) * 2 + FOOTER_SIZE:
                return False
            fh.seek(size - FOOTER_SIZE - len(MAGIC))
            tail = fh.read()
    except OSError:
        return False
    return tail[-8:] == MAGIC and tail[0] == 0x02 and _U64.unpack_from(tail, 1)[0] == 20


@dataclass
class _Chunk:
    start_ns: int
    index: int
    offset: int  # of the compressed records in the file
    size: int
    compression: str
    uncompressed_size: int
    crc: int


@dataclass
class McapScan:
    """What is complete in an mcap read from its start (see module doc)."""

    path: Path
    size: int  # of the file [bytes]
    good_end: int  # bytes up to the end of the last record kept
    stop_reason: str  # why the scan stopped ('' at a footer)
    connections: list[Any] = field(default_factory=list)  # rosbags Connection, msgcount filled in
    chunks: list[_Chunk] = field(default_factory=list)
    message_count: int = 0
    start_ns: int = 0  # first and last receive time [ns] of the messages kept (0, 0: none)
    end_ns: int = 0

    def messages(self, connections: Collection[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, receive time [ns], raw CDR) of ``connections``, by receive time (chunks merged)."""
        wanted = {c.id: c for c in connections}
        with self.path.open("rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            sources = [self._chunk_messages(buf, ch, wanted) for ch in self.chunks]
            for t, _, k, conn, data in heapq.merge(*sources):
                if k >= 0:
                    yield conn, t, data

    def _chunk_messages(self, buf: mmap.mmap, ch: _Chunk, wanted: dict[int, Any]) -> Iterator[tuple]:
        # A first entry at the chunk's start time: merging opens a chunk only when its turn comes.
        yield ch.start_ns, ch.index, -1, None, None
        records = _records_of(buf, ch)
        msgs = [(t, ch.index, k, wanted[cid], data)
                for k, (cid, t, data) in enumerate(_messages_in(records)) if cid in wanted]
        msgs.sort(key=lambda m: (m[0], m[2]))
        yield from msgs


def scan_mcap(path: Path) -> McapScan:
    """Walk ``path`` record by record (see module doc); :class:`McapScanError` if it is not an mcap."""
    with path.open("rb") as fh:
        size = fh.seek(0, 2)
        if size < len(MAGIC):
            raise McapScanError(f"the file has {size} bytes, not even the 8 of the mcap magic")
        if size == len(MAGIC):
            fh.seek(0)
            if fh.read() != MAGIC:
                raise McapScanError("not an mcap file (no mcap magic)")
            raise McapScanError("the file ends after its 8 magic bytes: no header, no message")
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as buf:
            return _scan(path, buf, size)


def _scan(path: Path, buf: mmap.mmap, size: int) -> McapScan:
    if buf[:8] != MAGIC:
        raise McapScanError("not an mcap file (no mcap magic)")
    if size < 17 or buf[8] != 0x01 or 17 + _U64.unpack_from(buf, 9)[0] > size:
        raise McapScanError(f"the file ends after {size} bytes, inside the mcap header: no message")
    pos = 17 + _U64.unpack_from(buf, 9)[0]
    scan = McapScan(path, size, pos, "")
    schemas: dict[int, tuple[str, str, str]] = {}
    channels: dict[int, tuple[int, str, str, bytes]] = {}
    counts: dict[int, int] = defaultdict(int)
    t_lo, t_hi = 2**63 - 1, -1
    while True:
        if pos == size:
            scan.stop_reason = f"the file ends after its last complete record, at byte {size}"
            break
        if pos + 9 > size:
            scan.stop_reason = f"a record at byte {pos} is cut off by the end of the file at byte {size}"
            break
        op, length = buf[pos], _U64.unpack_from(buf, pos + 1)[0]
        end = pos + 9 + length
        if end > size:
            scan.stop_reason = f"a record at byte {pos} is cut off by the end of the file at byte {size}"
            break
        try:
            if op == 0x06:
                ch = _chunk_at(buf, pos + 9, end, len(scan.chunks))
                found: list[tuple[int, int]] = []
                for rop, rec in _records(_records_of(buf, ch)):
                    _take(rop, rec, schemas, channels, found)
                for cid, t in found:
                    counts[cid] += 1
                    t_lo, t_hi = min(t_lo, t), max(t_hi, t)
                if found:
                    ch.start_ns = min(t for _, t in found)
                scan.chunks.append(ch)
            elif op in (0x02, 0x0F):  # footer or data end: the data section is complete
                scan.good_end = end
                break
            else:  # schemas, channels and messages outside chunks; indexes and the rest are skipped
                found = []
                _take(op, memoryview(buf)[pos + 9:end], schemas, channels, found)
                if found:  # rosbags puts messages in chunks: a loose one is not worth a second path
                    raise ValueError("a message outside a chunk")
        except (ValueError, IndexError, struct.error, UnicodeDecodeError, KeyError, OverflowError) as err:
            scan.stop_reason = f"the record at byte {pos} is corrupt ({err}), the {size - pos} bytes from it skipped"
            break
        pos = end
        scan.good_end = end
    scan.message_count = sum(counts.values())
    if scan.message_count:
        scan.start_ns, scan.end_ns = t_lo, t_hi
    scan.connections = [_connection(cid, ch, schemas, counts[cid]) for cid, ch in sorted(channels.items())]
    return scan


def _chunk_at(buf: mmap.mmap, lo: int, hi: int, index: int) -> _Chunk:
    start, _, usize, crc = _CHUNK_HEAD.unpack_from(buf, lo)
    n = _U32.unpack_from(buf, lo + 28)[0]
    compression = bytes(buf[lo + 32:lo + 32 + n]).decode()
    p = lo + 32 + n
    csize = _U64.unpack_from(buf, p)[0]
    if p + 8 + csize > hi:
        raise ValueError("chunk data longer than its record")
    ch = _Chunk(start, index, p + 8, csize, compression, usize, crc)
    _records_of(buf, ch)  # decompresses and checks the CRC now, so a bad chunk ends the scan here
    return ch


def _records_of(buf: mmap.mmap, ch: _Chunk) -> bytes:
    data = bytes(buf[ch.offset:ch.offset + ch.size])
    if ch.compression == "zstd":
        from rosbags.rosbag2.storage_mcap import zstd

        data = zstd.decompress(data)
    elif ch.compression == "lz4":
        from lz4.frame import decompress

        data = decompress(data)
    elif ch.compression:
        raise ValueError(f"unknown chunk compression {ch.compression!r}")
    if len(data) != ch.uncompressed_size:
        raise ValueError(f"chunk of {len(data)} bytes, its header says {ch.uncompressed_size}")
    if ch.crc and crc32(data) != ch.crc:
        raise ValueError("chunk CRC mismatch")
    return data


def _records(data: bytes | memoryview) -> Iterator[tuple[int, memoryview]]:
    view, pos, n = memoryview(data), 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise ValueError("a record cut off inside a chunk")
        length = _U64.unpack_from(view, pos + 1)[0]
        if pos + 9 + length > n:
            raise ValueError("a record longer than its chunk")
        yield view[pos], view[pos + 9:pos + 9 + length]
        pos += 9 + length


def _messages_in(data: bytes) -> Iterator[tuple[int, int, bytes]]:
    for op, rec in _records(data):
        if op == 0x05:
            cid, _, t, _ = _MESSAGE_HEAD.unpack_from(rec)
            yield cid, t, bytes(rec[22:])


def _take(op: int, rec: memoryview, schemas: dict, channels: dict, found: list[tuple[int, int]]) -> None:
    """Register a schema or channel record, or note a message's (channel, time) in ``found``."""
    if op == 0x03:
        sid = _U16.unpack_from(rec)[0]
        name, p = _string(rec, 2)
        encoding, p = _string(rec, p)
        data, _ = _string(rec, p)
        schemas[sid] = (name, encoding, data)
    elif op == 0x04:
        cid, sid = struct.unpack_from("<HH", rec)
        topic, p = _string(rec, 4)
        encoding, p = _string(rec, p)
        n = _U32.unpack_from(rec, p)[0]
        if p + 4 + n > len(rec):
            raise ValueError("channel metadata longer than its record")
        channels[cid] = (sid, topic, encoding, bytes(rec[p + 4:p + 4 + n]))
    elif op == 0x05:
        cid, _, t, _ = _MESSAGE_HEAD.unpack_from(rec)
        if cid not in channels:
            raise ValueError(f"a message on channel {cid}, which no channel record defines")
        found.append((cid, t))


def _string(rec: memoryview, p: int) -> tuple[str, int]:
    n = _U32.unpack_from(rec, p)[0]
    if p + 4 + n > len(rec):
        raise ValueError("a string longer than its record")
    return bytes(rec[p + 4:p + 4 + n]).decode(), p + 4 + n


def _connection(cid: int, ch: tuple[int, str, str, bytes], schemas: dict, count: int) -> Any:
    sid, topic, encoding, meta = ch
    name, fmt, data = schemas.get(sid, ("", "", ""))
    msgdef = MessageDefinition(_FORMATS.get(fmt, MessageDefinitionFormat.NONE), data if fmt in _FORMATS else "")
    return Connection(cid, topic, name, msgdef, "", count, ConnectionExtRosbag2(encoding, _qos(meta)), None)


def _qos(meta: bytes) -> list:
    """The offered QoS profiles stored in a channel's metadata (none if they do not parse)."""
    view, p = memoryview(meta), 0
    try:
        while p < len(view):
            key, p = _string(view, p)
            value, p = _string(view, p)
            if key == "offered_qos_profiles":
                return parse_qos(value)
    except Exception:  # QoS is informational: a bad one must not lose the data
        return []
    return []
