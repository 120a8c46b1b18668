"""The compiled CSV writer (elastic_pm_dyn/csv_text.py) against Python's own '%.17g' and np.savetxt.

Python's formatting of doubles (David Gay's correctly rounded dtoa) is the independent
reference: every number must come out as the same text, so a CSV written by ``simulate``
is the one np.savetxt(fmt="%.17g") wrote before.
"""

from __future__ import annotations

import io

import numpy as np

from elastic_pm_dyn import csv_text
from elastic_pm_dyn.csv_text import format_float, table_bytes, table_text, write_table

EDGES = [0.0, -0.0, 1.0, -1.0, 0.1, 0.5, 2.5, 1e-5, 1e-4, 9.9999999999999995e-5, 1e16, 1e17, 9.999999999999999e16,
         123456789012345678.0, 5e-324, 2.2250738585072014e-308, 2.2250738585072009e-308, 1.7976931348623157e308,
         1e22, 1e23, 2.0**53, 2.0**53 + 2, 1e-300, 1e300, 100.0, 1e-7, 7e22, 4.35e-5, np.inf, -np.inf, np.nan,
         -np.nan, 1e308, 1e-323, 9.8813129168249309e-324, 1e16 - 2, 1e-4 - 1.3552527156068805e-20]


def test_edge_values_format_as_python_does() -> None:
    for x in EDGES:
        assert format_float(x) == f"{x:.17g}", x
    buf = np.zeros(40, dtype=np.uint8)  # the fallback for undecided near ties (none known): Python's text
    n = csv_text._python_format(-0.1, buf, 0)
    assert buf[:n].tobytes() == b"0.10000000000000001"


def test_random_doubles_of_every_kind_format_as_savetxt_does() -> None:
    """Random bit patterns (all exponents, subnormals), decimals of a few digits, and dyadic
    numbers with exact ties at the 17th digit (rounded half to even)."""
    rng = np.random.default_rng(5)
    bits = rng.integers(0, 2**64 - 1, 60000, dtype=np.uint64, endpoint=True)
    values = np.concatenate([
        bits.view(np.float64),
        rng.standard_normal(20000) * 10.0 ** rng.integers(-20, 20, 20000),
        np.round(rng.standard_normal(20000) * 1000, 3),
        rng.integers(-10**6, 10**6, 20000) / 2.0 ** rng.integers(0, 60, 20000),
    ])
    table = values.reshape(-1, 8)
    ref = io.StringIO()
    np.savetxt(ref, table, delimiter=",", fmt="%.17g")
    assert table_text(table) == ref.getvalue()


def test_random_bit_patterns_and_neighbours_of_powers_of_ten_format_as_python_does() -> None:
    """200k random doubles of every exponent, and every power of ten's double with its 40
    neighbours either side: where floor(log10 |x|) changes (the exponent tables)."""
    rng = np.random.default_rng(11)
    powers = np.array([float(f"1e{k}") for k in range(-323, 309)]).view(np.int64)
    near = (powers[:, None] + np.arange(-40, 41)).ravel().view(np.float64)
    values = np.concatenate([rng.integers(0, 2**64 - 1, 200000, dtype=np.uint64, endpoint=True).view(np.float64),
                             near[np.isfinite(near)]])
    values = values[: len(values) // 10 * 10]
    assert table_text(values.reshape(-1, 10)) == "".join(
        ",".join(f"{x:.17g}" for x in row) + "\n" for row in values.reshape(-1, 10).tolist())


def test_write_table_in_chunks_writes_table_bytes(monkeypatch) -> None:
    rng = np.random.default_rng(3)
    table = rng.standard_normal((103, 7)) * 10.0 ** rng.integers(-8, 8, (103, 7))
    monkeypatch.setattr(csv_text, "CHUNK_BYTES", 1000)  # 5 rows a chunk, the last one short
    out = io.BytesIO()
    write_table(out, table)
    assert out.getvalue() == table_bytes(table) == table_text(table).encode("ascii")
