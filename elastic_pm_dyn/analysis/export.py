"""``elastic-pm-dyn export``: one CSV per topic of a bag, streamed (bounded memory).

Columns are the message fields flattened with dots: ``header.stamp`` (seconds, exact
to the nanosecond), ``position.left_motor`` (numeric arrays named by the message's
``name`` list where it has one, else by index), ``status.0.values.command_age_s``
(key-value lists by key). The first message of a topic fixes its columns; values of
later messages are matched by column name, cells they lack stay empty, and values with
no column are counted and reported. Every row starts with ``receive_time_ns``, the
bag's receive time.
"""

from __future__ import annotations

import contextlib
import csv
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.msgtypes import DURATION, KEY_VALUE, NS, TIME, stamp_ns
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.output_files import OutputError, staged_files

MAX_ARRAY = 256  # longer arrays (images, point clouds) are exported as their length only
TIME_TYPES = (TIME, DURATION)


@dataclass
class ExportedTopic:
    topic: str
    msgtype: str
    file: Path
    rows: int
    columns: int
    dropped: int  # values that had no column (a later message named other joints, ...)
    long_arrays: list[str]  # fields exported as their length only


def _time_text(stamp: Any) -> str:
    """Seconds with all nine decimals (a float would round nanoseconds of epoch times)."""
    ns = stamp_ns(stamp)
    return f"{'-' if ns < 0 else ''}{abs(ns) // NS}.{abs(ns) % NS:09d}"


def _scalar(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    return str(v)


class Flattener:
    """Message -> {column: text} using the typestore's field definitions."""

    def __init__(self, typestore: Any):
        self.fielddefs = typestore.fielddefs
        self.long_arrays: set[str] = set()

    def fields(self, msgtype: str) -> list[str]:
        return [name for name, _ in self.fielddefs[msgtype][1]]

    def flatten(self, msg: Any, msgtype: str, prefix: str = "", out: dict | None = None) -> dict[str, str]:
        out = {} if out is None else out
        if msgtype in TIME_TYPES:
            out[prefix.rstrip(".")] = _time_text(msg)
            return out
        names = getattr(msg, "name", None)
        labels = list(names) if isinstance(names, list) and all(isinstance(n, str) for n in names) else None
        for fname in self.fields(msgtype):
            value = getattr(msg, fname)
            key = f"{prefix}{fname}"
            if fname == "name" and labels is not None:
                continue  # the names label the array columns
            self._value(value, key, labels, out)
        return out

    def _value(self, value: Any, key: str, labels: list[str] | None, out: dict) -> None:
        msgtype = getattr(value, "__msgtype__", None)
        if msgtype is not None:
            self.flatten(value, msgtype, key + ".", out)
        elif isinstance(value, np.ndarray) or (isinstance(value, list) and value
                                               and not hasattr(value[0], "__msgtype__")
                                               and not isinstance(value[0], str)):
            arr = np.asarray(value)
            if arr.size > MAX_ARRAY:
                self.long_arrays.add(key)
                out[f"{key}.len"] = str(arr.size)
                return
            use = labels if labels is not None and len(labels) == arr.size else None
            for k, v in enumerate(arr.ravel()):
                out[f"{key}.{use[k] if use else k}"] = _scalar(v)
        elif isinstance(value, list):
            if value and isinstance(value[0], str):
                out[key] = ";".join(value)
            elif value and _is_key_value(value[0]):
                for kv in value:
                    out[f"{key}.{kv.key}"] = kv.value
            else:
                for k, item in enumerate(value):
                    self._value(item, f"{key}.{k}", None, out)
        else:
            out[key] = _scalar(value)


def _is_key_value(x: Any) -> bool:
    return getattr(x, "__msgtype__", "") == KEY_VALUE


def csv_name(topic: str) -> str:
    """'/robot/joint_states' -> 'robot__joint_states.csv'."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", topic.strip("/").replace("/", "__") or "root") + ".csv"


def export_bag(bag: str | Path, out: str | Path, topics: Sequence[str] | None = None) -> list[ExportedTopic]:
    """Write ``out/<topic>.csv`` for every topic of ``bag`` (or the named ones); see module doc."""
    bag, out = Path(bag), Path(out)
    with open_bag(bag) as reader:
        reader.require_messages()
        table = reader.topics()
        wanted = list(table) if not topics else [t if t in table or t.startswith("/") else "/" + t for t in topics]
        unknown = [t for t in wanted if t not in table]
        if unknown:
            raise BagError(f"{bag}: no topic {', '.join(unknown)} (the bag has {', '.join(table) or 'none'})")
        flat = {t: Flattener(reader.typestore) for t in wanted}
        writers: dict[str, tuple[Any, Any, list[str], list[int]]] = {}
        conns = [c for c in reader.connections if c.topic in wanted]
        undecodable = sorted({c.topic for c in conns if not reader.can_decode(c.msgtype)})
        if undecodable:
            raise BagError(f"{bag}: no message definition for {', '.join(undecodable)}")
        files: dict[str, Path] = {}
        current = out
        # every CSV into a staging folder, moved into out when all are complete: none, and no
        # folder, on an error
        with staged_files(out) as stage:
            try:
                for conn, t_ns, msg in reader.decoded(conns):
                    row = flat[conn.topic].flatten(msg, conn.msgtype)
                    if conn.topic not in writers:
                        files[conn.topic] = current = out / csv_name(conn.topic)
                        fh = (stage / csv_name(conn.topic)).open("w", newline="", encoding="utf-8")
                        w = csv.writer(fh)
                        cols = list(row)
                        w.writerow(["receive_time_ns", *cols])
                        writers[conn.topic] = (fh, w, cols, [0, 0])
                    fh, w, cols, counts = writers[conn.topic]
                    current = files[conn.topic]
                    w.writerow([t_ns, *(row.pop(c, "") for c in cols)])
                    counts[0] += 1
                    counts[1] += len(row)  # left over: no column for them
                for topic, (fh, *_) in writers.items():
                    current = files[topic]
                    fh.close()  # flushes: a full disk shows here
            except OSError as err:
                raise OutputError(f"cannot write {current}: {err.strerror or err}") from None
            finally:
                for fh, *_ in writers.values():
                    with contextlib.suppress(OSError):
                        fh.close()
    result = []
    for topic in wanted:
        if topic in writers:
            _, _, cols, (rows, dropped) = writers[topic]
            result.append(ExportedTopic(topic, table[topic][0], files[topic], rows, len(cols) + 1, dropped,
                                        sorted(flat[topic].long_arrays)))
    return result
