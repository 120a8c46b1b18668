"""Property: a bag truncated or bit-flipped anywhere either reads (possibly as a cut recording)
or raises one one-line BagError; never another exception, never a hang.

Both storages, finished bags and recordings whose writer never closed them; a fixed
example budget (derandomised) keeps the run short and the same every time;
``pytest --fuzz-long`` (or ELASTIC_PM_DYN_FUZZ=long) runs 50x as many new ones.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from conftest import fuzz_settings
from hypothesis import given, settings
from hypothesis import strategies as st
from test_bag_errors import N, _joint_states, write_states

from elastic_pm_dyn.bags.decode import Decoder
from elastic_pm_dyn.bags.errors import BagError
from elastic_pm_dyn.bags.msgtypes import JOINT_STATE
from elastic_pm_dyn.bags.reader import open_bag
from elastic_pm_dyn.bags.writer import BagWriter

SOURCES = [(s, finished) for s in ("mcap", "sqlite3") for finished in (True, False)]


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict[tuple[str, bool], Path]:
    """Each storage finished, and left open as a kill leaves it (flushed every 60 messages)."""
    root = tmp_path_factory.mktemp("fuzz_sources")
    out = {}
    for storage in ("mcap", "sqlite3"):
        out[storage, True] = write_states(root / f"{storage}_finished", storage)
        path = root / f"{storage}_open"
        ns, msgs = _joint_states(N)
        w = BagWriter(path, storage)
        c = w.add_connection("/joint_states", JOINT_STATE)
        for k in range(N):
            w.write(c, int(ns[k]), msgs[k].tobytes())
            if (k + 1) % 60 == 0:
                w.flush()
        w.abort()  # what a kill leaves: the unfinished metadata.yaml, the flushed data
        out[storage, False] = path
    return out


def read_all(path: Path) -> int:
    """Open and read every message as the package's readers do (raw, fast decoder, rosbags)."""
    with open_bag(path) as bag:
        dec = bag.decoder()
        n = 0
        for conn, _, raw in bag.messages(bag.connections):
            if conn.msgtype == JOINT_STATE:
                dec.joint_state(raw)
            n += 1
        for _ in bag.decoded(bag.connections):
            pass
        return n


def check(path: Path) -> None:
    try:
        read_all(path)
    except BagError as err:
        text = str(err)
        assert text and "\n" not in text and len(text) < 2000, text


@settings(fuzz_settings(100), deadline=3000)  # a 3 s deadline: a hang fails the example
@given(source=st.sampled_from(SOURCES), where=st.floats(0.0, 1.0), damage=st.sampled_from(["truncate", "flip"]),
       flips=st.lists(st.tuples(st.floats(0.0, 1.0), st.integers(0, 7)), min_size=1, max_size=4))
def test_damaged_bags_read_or_fail_in_one_line(sources, tmp_path_factory, source, where, damage, flips):
    bag = tmp_path_factory.mktemp("fuzz") / "bag"
    shutil.copytree(sources[source], bag)
    f = next(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
    data = bytearray(f.read_bytes())
    if damage == "truncate":
        del data[int(where * len(data)):]
    else:
        for at, bit in flips:
            data[min(int(at * len(data)), len(data) - 1)] ^= 1 << bit
    f.write_bytes(bytes(data))
    check(bag)
    check(f)  # the storage file on its own


def test_decoder_on_garbage_falls_back_or_raises_bag_error(sources):
    """The fast decoders' fallback is rosbags through the bag: its errors are BagError too."""
    with open_bag(sources["mcap", True]) as bag:
        dec: Decoder = bag.decoder()
        for raw in (b"", b"\x00\x01\x00\x00", b"\x00\x01\x00\x00" + b"\xff" * 40):
            with pytest.raises(BagError):
                dec.joint_state(raw)
