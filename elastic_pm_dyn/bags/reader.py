"""Open a rosbag2 bag and read it: the one way into a bag, for every reader of the package.

:func:`open_bag` takes a bag directory or a single ``.mcap``/``.db3`` file, mcap or
sqlite3, with or without the message definitions stored (our ``BranchForces`` and Jazzy's
types stand in where the bag has none, or only some), and turns whatever rosbags or a
broken storage file raises into a one-line :class:`~elastic_pm_dyn.bags.errors.BagError`
naming the bag, when opening as when reading messages.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader

from elastic_pm_dyn.bags.decode import Decoder
from elastic_pm_dyn.bags.errors import READ_ERRORS, BagError, one_line
from elastic_pm_dyn.bags.typestore import make_typestore


def storage_of(path: Path) -> str:
    """'mcap' or 'sqlite3', from the storage files of a bag directory (or the file itself)."""
    files = [path] if path.is_file() else list(path.iterdir())
    suffixes = {p.suffix for p in files}
    return "mcap" if ".mcap" in suffixes else "sqlite3" if ".db3" in suffixes else "?"


@contextmanager
def open_bag(path: str | Path) -> Iterator[Bag]:
    """The open :class:`Bag` at ``path``; closed on leaving the ``with`` block."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        files = sorted(p.name for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
        hint = f"; to read a storage file without it, pass {path / files[0]}" if files else ""
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml{hint})")
    try:
        reader = AnyReader([path], default_typestore=make_typestore())
        reader.open()
    except READ_ERRORS as err:
        hint = ("; an mcap whose recorder was killed lacks its footer: repair it with `mcap recover`"
                if "end magic" in str(err) else "")
        raise BagError(f"{path}: cannot open the bag (truncated or corrupt?): {one_line(err)}{hint}") from None
    try:
        _complete_typestore(reader)
        yield Bag(path, reader)
    finally:
        reader.close()


def _complete_typestore(reader: AnyReader) -> None:
    """Add our types (and Jazzy's) for connections whose bag carries no definition.

    AnyReader uses its default typestore only when *no* connection has a definition; a
    bag with definitions for some types and not for others would leave those undecodable.
    """
    have = reader.typestore.fielddefs
    missing = {c.msgtype for c in reader.connections if c.msgtype not in have}
    if missing:
        defaults = make_typestore().fielddefs
        reader.typestore.register({k: v for k, v in defaults.items() if k not in have})


class Bag:
    """An open bag: its connections (rosbags ``Connection``: ``topic``, ``msgtype``, ``id``),
    topics and messages; errors of the bag become :class:`BagError`."""

    def __init__(self, path: Path, reader: AnyReader):
        self.path = path
        self.storage = storage_of(path)
        self._reader = reader
        self.connections: list[Any] = list(reader.connections)
        self.typestore = reader.typestore
        self.start_ns = int(reader.start_time)
        self.end_ns = int(reader.end_time)

    def topics(self) -> dict[str, tuple[str, int]]:
        """Every topic: name -> (message type, message count)."""
        return {name: (info.msgtype or "?", int(info.msgcount)) for name, info in self._reader.topics.items()}

    def can_decode(self, msgtype: str) -> bool:
        return msgtype in self.typestore.fielddefs

    def messages(self, connections: Sequence[Any]) -> Iterator[tuple[Any, int, bytes]]:
        """(connection, receive time [ns], raw CDR) of the given connections, in bag order."""
        it = self._reader.messages(connections=connections)
        n, t_last = 0, 0  # messages read so far, the receive time of the last: for the error
        while True:
            try:
                conn, t_ns, raw = next(it)
            except StopIteration:
                return
            except READ_ERRORS as err:
                raise self._corrupt(err, n, t_last) from None
            yield conn, t_ns, raw
            n += 1
            t_last = t_ns

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
