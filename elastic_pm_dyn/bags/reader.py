"""Open a rosbag2 bag and read it: the one way into a bag, for every reader of the package.

:func:`open_bag` takes a bag directory or a single ``.mcap``/``.db3`` file, mcap or
sqlite3, with or without the message definitions stored (our ``BranchForces`` and Jazzy's
types stand in where the bag has none, or only some), and turns whatever rosbags or a
broken storage file raises into a one-line :class:`~elastic_pm_dyn.bags.errors.BagError`
naming the bag, when opening as when reading messages.

A recording whose writer was killed (``metadata.yaml`` still marked unfinished, or an
mcap without its footer) is read as far as it is complete: an mcap's complete chunks
(:mod:`~elastic_pm_dyn.bags.mcap_scan`), a sqlite3 file's committed rows (a journal the
kill left behind rolled back on a copy). One warning line says that it was cut off,
where, and what was recovered (also in :attr:`Bag.cut`). A *finished* bag whose mcap
lost its end was damaged afterwards: that is an error, and ``bag-repair`` recovers it.
"""

from __future__ import annotations

import logging
import shutil
import sqlite3
import tempfile
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import MessageDefinitionFormat
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from elastic_pm_dyn.bags.decode import Decoder
from elastic_pm_dyn.bags.errors import READ_ERRORS, BagError, one_line
from elastic_pm_dyn.bags.mcap_scan import McapScan, McapScanError, has_footer, scan_mcap
from elastic_pm_dyn.bags.metadata import UNFINISHED, recording_state
from elastic_pm_dyn.bags.typestore import make_typestore

log = logging.getLogger("elastic_pm_dyn.bags")
MAX_METADATA_BYTES = 16 * 2**20  # a bag's metadata.yaml has a few kB per topic
Messages = Callable[[Sequence[Any]], Iterator[tuple[Any, int, bytes]]]


def storage_of(path: Path) -> str:
    """'mcap' or 'sqlite3', from the storage files of a bag directory (or the file itself)."""
    files = [path] if path.is_file() else list(path.iterdir())
    suffixes = {p.suffix for p in files}
    return "mcap" if ".mcap" in suffixes else "sqlite3" if ".db3" in suffixes else "?"


def _storage_files(path: Path) -> list[Path]:
    return [path] if path.is_file() else sorted(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))


@contextmanager
def open_bag(path: str | Path) -> Iterator[Bag]:
    """The open :class:`Bag` at ``path``; closed on leaving the ``with`` block."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if not path.is_dir() and not path.is_file():  # a device or FIFO would never end, or block
        raise BagError(f"{path}: not a bag (a device or FIFO?): give a bag directory or its .mcap/.db3 file")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        files = sorted(p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
        hint = f"; to read a storage file without it, pass {path / files[0]}" if files else ""
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml{hint})")
    meta_dir = path if path.is_dir() else path.parent
    meta = meta_dir / "metadata.yaml"
    if meta.is_file() and meta.stat().st_size > MAX_METADATA_BYTES:  # rosbags would read and parse it whole
        raise BagError(f"{meta}: {meta.stat().st_size} bytes, more than the {MAX_METADATA_BYTES >> 20} MiB "
                       "a bag's metadata.yaml may have")
    state = recording_state(meta_dir) if (meta_dir / "metadata.yaml").is_file() else None
    files = _storage_files(path)
    special = [f.name for f in files if not f.is_file()]
    if special:
        raise BagError(f"{path}: {', '.join(special)} is not a regular file (a device or FIFO?)")
    storage = storage_of(path)
    with ExitStack() as stack:
        if storage == "mcap" and len(files) == 1 and not has_footer(files[0]):
            if state is not None and state != UNFINISHED:
                raise BagError(f"{path}: bag is truncated or corrupt: {files[0].name} has lost its end (no mcap "
                               "footer) although metadata.yaml says the bag was finished; `elastic-pm-dyn "
                               f"bag-repair {path}` copies what is complete")
            bag = recover_mcap(path, files[0])
        elif state == UNFINISHED and len(files) == 1:
            # metadata.yaml lists no messages yet: the storage file alone says what is there.
            bag = _from_reader(path, _open_reader(stack, [_committed_sqlite(stack, files[0])]))
            if storage == "sqlite3":
                bag.cut = _cut_text(path, "its writer never closed it: metadata.yaml still says unfinished", bag)
        else:
            bag = _from_reader(path, _open_reader(stack, [path]))
        if bag.cut:
            log.warning(f"warning: {bag.cut}")
        yield bag


def _open_reader(stack: ExitStack, paths: list[Path]) -> AnyReader:
    try:
        reader = AnyReader(paths, default_typestore=make_typestore())
        reader.open()
    except READ_ERRORS as err:
        hint = ("; an mcap whose writer was killed lacks its footer: `elastic-pm-dyn bag-repair` recovers it"
                if "end magic" in str(err) else "")
        raise BagError(f"{paths[0]}: cannot open the bag (truncated or corrupt?): {one_line(err)}{hint}") from None
    stack.callback(reader.close)
    try:
        _complete_typestore(reader.typestore, reader.connections)
    except READ_ERRORS as err:
        raise BagError(f"{paths[0]}: cannot use the message definitions of the bag: {one_line(err)}") from None
    return reader


def _from_reader(path: Path, reader: AnyReader) -> Bag:
    count = int(reader.message_count)
    return Bag(path, storage_of(path), list(reader.connections), reader.typestore,
               lambda conns: reader.messages(connections=conns), count,
               int(reader.start_time) if count else 0, int(reader.end_time) if count else 0)


def _committed_sqlite(stack: ExitStack, db: Path) -> Path:
    """``db``, or a copy with the transaction a kill interrupted rolled back (rosbags reads
    a database as immutable and would take a half-written commit as it is)."""
    side = [p for p in (db.with_name(db.name + "-journal"), db.with_name(db.name + "-wal"))
            if p.is_file() and p.stat().st_size]
    if db.suffix != ".db3" or not side:
        return db
    tmp = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="bag_recovery_")))
    for p in (db, *side):
        shutil.copyfile(p, tmp / p.name)
    try:
        con = sqlite3.connect(tmp / db.name)
        try:
            con.execute("SELECT count(*) FROM sqlite_master").fetchone()  # rolls a hot journal back
            con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            con.close()
    except sqlite3.Error as err:
        raise BagError(f"{db}: cannot recover the database its writer left: {one_line(err)}") from None
    return tmp / db.name


def recover_mcap(path: Path, file: Path) -> Bag:
    """The bag of an mcap without footer: its complete chunks (``cut`` says what was recovered)."""
    try:
        scan = scan_mcap(file)
    except McapScanError as err:
        raise BagError(f"{path}: bag is truncated or corrupt: nothing to recover: {err}") from None
    except OSError as err:
        raise BagError(f"{path}: cannot read the bag: {err.strerror or one_line(err)}") from None
    try:
        typestore = _typestore_of(scan)
    except READ_ERRORS as err:
        raise BagError(f"{path}: cannot use the message definitions of the bag: {one_line(err)}") from None
    bag = Bag(path, "mcap", scan.connections, typestore, scan.messages, scan.message_count,
              scan.start_ns, scan.end_ns + 1 if scan.message_count else 0)
    bag.cut = _cut_text(path, f"no mcap footer: {scan.stop_reason}", bag)
    return bag


def _typestore_of(scan: McapScan) -> Typestore:
    """The types of the bag's own definitions (as rosbags' AnyReader builds them), ours for the rest."""
    typs: dict[str, Any] = {}
    for c in scan.connections:
        if c.msgdef.format == MessageDefinitionFormat.MSG:
            typs.update(get_types_from_msg(c.msgdef.data, c.msgtype))
        elif c.msgdef.format == MessageDefinitionFormat.IDL:
            sep = "=" * 80 + "\n"
            parts = c.msgdef.data.split(sep)[1:] if c.msgdef.data.startswith(f"{sep}IDL: ") else [None]
            for part in parts:
                typs.update(get_types_from_idl(c.msgdef.data if part is None else part.split("\n", 1)[1]))
    if not typs:
        return make_typestore()
    store = get_typestore(Stores.EMPTY)
    store.register(typs)
    _complete_typestore(store, scan.connections)
    return store


def _cut_text(path: Path, why: str, bag: Bag) -> str:
    """One line: cut off, why, where (the last receive time) and what was recovered."""
    if not bag.message_count:
        return f"{path}: the recording was cut off ({why}); no message was recovered"
    per_topic = ", ".join(f"{t} {n}" for t, (_, n) in bag.topics().items() if n)
    last = (bag.end_ns - 1) * 1e-9
    return (f"{path}: the recording was cut off ({why}); recovered {bag.message_count} messages ({per_topic}) "
            f"up to bag time {last:.6f} s, {last - bag.start_ns * 1e-9:.3f} s after the first; "
            f"`elastic-pm-dyn bag-repair {path}` writes a finished copy")


def _complete_typestore(store: Typestore, connections: Sequence[Any]) -> None:
    """Add our types (and Jazzy's) for connections whose bag carries no definition.

    AnyReader uses its default typestore only when *no* connection has a definition; a
    bag with definitions for some types and not for others would leave those undecodable.
    """
    have = store.fielddefs
    missing = {c.msgtype for c in connections if c.msgtype not in have}
    if missing:
        defaults = make_typestore().fielddefs
        store.register({k: v for k, v in defaults.items() if k not in have})


class Bag:
    """An open bag: its connections (rosbags ``Connection``: ``topic``, ``msgtype``, ``id``),
    topics and messages; errors of the bag become :class:`BagError`.

    ``start_ns``/``end_ns``: the first receive time and the last + 1 [ns] (both 0 in a bag
    without messages: its duration is 0). ``cut``: None, or the line saying that the
    recording was cut off and what was recovered."""

    def __init__(self, path: Path, storage: str, connections: list[Any], typestore: Typestore,
                 messages: Messages, message_count: int, start_ns: int, end_ns: int):
        self.path = path
        self.storage = storage
        self.connections = connections
        self.typestore = typestore
        self._messages = messages
        self.message_count = message_count
        self.start_ns = start_ns
        self.end_ns = end_ns
        self.cut: str | None = None
        self._count_warned = False

    def topics(self) -> dict[str, tuple[str, int]]:
        """Every topic: name -> (message type, message count)."""
        out: dict[str, tuple[str, int]] = {}
        for c in self.connections:
            msgtype, n = out.get(c.topic, (c.msgtype, 0))
            out[c.topic] = (msgtype if msgtype == c.msgtype else "?", n + int(c.msgcount))
        return out

    def require_messages(self) -> None:
        """:class:`BagError` if the bag holds no message at all."""
        if not self.message_count:
            cut = f" ({self.cut})" if self.cut else ""
            raise BagError(f"{self.path}: the bag is empty: no messages{cut}")

    def can_decode(self, msgtype: str) -> bool:
        return msgtype in self.typestore.fielddefs

    def messages(self, connections: Sequence[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, receive time [ns], raw CDR) of the given connections, in bag order."""
        if not connections:  # rosbags would take an empty list for "every connection"
            return
        n, t_last = 0, 0  # messages read so far, the receive time of the last: for the error
        try:
            it = self._messages(connections)
        except READ_ERRORS as err:
            raise self._corrupt(err, n, t_last) from None
        while True:
            try:
                conn, t_ns, raw = next(it)
            except StopIteration:
                self._check_count(connections, n)
                return
            except READ_ERRORS as err:
                raise self._corrupt(err, n, t_last) from None
            yield conn, t_ns, raw
            n += 1
            t_last = t_ns

    def _check_count(self, connections: Sequence[Any], n: int) -> None:
        """A warning (once per bag) when a full read gave another number of messages than the bag
        says it holds: a damaged chunk without a CRC can lose a message without any error."""
        expected = sum(int(getattr(c, "msgcount", 0) or 0) for c in connections)
        if n == expected or not expected or self._count_warned:
            return
        self._count_warned = True
        topics = sorted({c.topic for c in connections})
        shown = ", ".join(topics[:3]) + (f" and {len(topics) - 3} more" if len(topics) > 3 else "")
        log.warning(f"warning: {self.path}: read {n} messages of {shown} but the bag's index says {expected}: "
                    "the bag is damaged (a chunk without CRC?); results are from the messages read")

    def decoded(self, connections: Sequence[Any]) -> Iterator[tuple[Any, int, Any]]:
        """(connection, receive time [ns], message object) of the given connections, in bag order."""
        decode = self.typestore.deserialize_cdr
        t_last = 0
        for n, (conn, t_ns, raw) in enumerate(self.messages(connections)):
            try:
                msg = decode(raw, conn.msgtype)
            except READ_ERRORS as err:
                raise self._corrupt(err, n, t_last) from None
            yield conn, t_ns, msg
            t_last = t_ns

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        """One message object from its raw CDR."""
        try:
            return self.typestore.deserialize_cdr(raw, msgtype)
        except READ_ERRORS as err:
            raise self._corrupt(err, 0, 0) from None

    def decoder(self) -> Decoder:
        """Fast decoding of the types read in bulk, this bag's definitions as the fallback."""
        return Decoder(self.deserialize)

    def _corrupt(self, err: BaseException, n: int, t_last_ns: int) -> BagError:
        when = f" after {n} messages (bag time {t_last_ns * 1e-9:.6f} s)" if n else ""
        return BagError(f"{self.path}: bag is truncated or corrupt{when}: {one_line(err)}")
