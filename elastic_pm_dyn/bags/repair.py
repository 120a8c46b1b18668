"""``elastic-pm-dyn bag-repair``: a finished copy of a bag cut off or damaged, with every message that can be read.

:func:`repair_bag` reads the source through :func:`~elastic_pm_dyn.bags.reader.open_bag`
(so a recording whose writer was killed gives its complete mcap chunks or committed
sqlite3 rows; a finished bag that lost its mcap footer is scanned the same way) and
writes a new bag in the same storage with the same topics, types and definitions: the
messages that deserialise, in bag order, closed properly (index, footer, metadata.yaml),
so that any rosbag2 reader opens it. Messages whose bytes do not deserialise are left
out and counted; reading stops at the first record the storage cannot give.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from elastic_pm_dyn.bags.errors import READ_ERRORS, BagError
from elastic_pm_dyn.bags.mcap_scan import has_footer
from elastic_pm_dyn.bags.reader import Bag, open_bag, recover_mcap, storage_of
from elastic_pm_dyn.bags.writer import BagWriter
from elastic_pm_dyn.output_files import atomic_dir


@dataclass
class RepairReport:
    """What :func:`repair_bag` wrote: ``out``, messages per topic, what it left out and why."""

    source: Path
    out: Path
    storage: str
    messages: dict[str, int] = field(default_factory=dict)  # topic -> messages written
    undecodable: dict[str, int] = field(default_factory=dict)  # topic -> messages left out (bad CDR)
    cut: str | None = None  # the source's cut-off line, if it was cut
    stopped: str | None = None  # why reading stopped early (a corrupt record), if it did

    @property
    def written(self) -> int:
        return sum(self.messages.values())

    def lines(self) -> list[str]:
        """The report as the command prints it."""
        out = [f"{self.out}: {self.written} messages ({self.storage}) from {self.source}"]
        out += [f"  {t}: {n}" for t, n in self.messages.items()]
        if self.undecodable:
            out.append("  left out (do not deserialise): "
                       + ", ".join(f"{t} {n}" for t, n in self.undecodable.items()))
        if self.cut:
            out.append(f"  source: {self.cut.split('; `elastic-pm-dyn bag-repair')[0]}")  # not its own advice
        if self.stopped:
            out.append(f"  reading stopped early: {self.stopped}")
        return out


def default_out(src: Path) -> Path:
    """``<bag>_repaired`` next to the bag (next to its directory for a storage file)."""
    bag_dir = src if src.is_dir() else src.parent if (src.parent / "metadata.yaml").is_file() else src
    return bag_dir.with_name(bag_dir.stem + "_repaired")


def repair_bag(src: str | Path, out: str | Path | None = None) -> RepairReport:
    """Write a finished copy of ``src`` at ``out`` (default :func:`default_out`; never overwritten)."""
    src = Path(src)
    out = Path(out) if out is not None else default_out(src)
    if out.exists():
        raise BagError(f"{out} exists already (a bag is never overwritten); choose another with --out")
    with _open_any(src) as bag:
        report = RepairReport(src, out, bag.storage, cut=bag.cut)
        if bag.storage not in ("mcap", "sqlite3"):
            raise BagError(f"{src}: no mcap or sqlite3 storage file to repair")
        with atomic_dir(out) as tmp:  # a repair stopped half-way leaves no half bag
            try:
                _copy(bag, BagWriter(tmp, bag.storage, typestore=bag.typestore), report)
            except BagError as err:  # name the user's path, not the temporary one
                raise BagError(str(err).replace(str(tmp), str(out))) from None
    return report


def _copy(bag: Bag, writer: BagWriter, report: RepairReport) -> None:
    """Every decodable message of ``bag`` into ``writer``, counted in ``report``. A corrupt
    record while reading stops the copy (what came before is kept); a write error raises."""
    with writer as w:
        conns = {}
        for c in bag.connections:
            if c.topic not in conns:
                conns[c.topic] = w.add_connection(c.topic, c.msgtype)
                report.messages[c.topic] = 0
        decode = bag.typestore.deserialize_cdr
        messages = iter(bag.messages(bag.connections))
        while True:
            try:
                c, t_ns, raw = next(messages)
            except StopIteration:
                break
            except BagError as err:  # a corrupt record in the middle: keep what came before it
                report.stopped = str(err)
                break
            try:
                decode(raw, c.msgtype)
            except READ_ERRORS:
                report.undecodable[c.topic] = report.undecodable.get(c.topic, 0) + 1
                continue
            try:
                w.write(conns[c.topic], t_ns, raw)
            except OSError as err:
                raise BagError(f"{w.path}: cannot write to the bag: {err.strerror or err}") from None
            report.messages[c.topic] += 1


@contextmanager
def _open_any(src: Path) -> Iterator[Bag]:
    """:func:`open_bag`, and for a finished mcap that lost its end, its complete chunks."""
    files = [src] if src.is_file() else sorted(src.glob("*.mcap")) if src.is_dir() else []
    if src.exists() and storage_of(src) == "mcap" and len(files) == 1 and not has_footer(files[0]):
        bag = recover_mcap(src, files[0])
        if not bag.message_count:
            raise BagError(f"{src}: nothing to repair: {bag.cut}")
        yield bag
        return
    with open_bag(src) as bag:
        yield bag
