"""Property: whatever a user feeds in, the answer is a result or one line.

Mutated model YAML (from the shipped models: lines deleted, duplicated or re-indented,
values swapped for wrong types, huge numbers, NaN/Inf, unknown tags, aliases, garbage
bytes, a cut file) loads or raises one one-line ModelError; the same through
``elastic-pm-dyn check`` exits 0 or 2 with one line and writes nothing. Mutated torque
CSVs load or raise one one-line InputError; simulate's numeric flags given NaN, Inf,
negative, huge, tiny or text values exit 0 or 2 with one line. Budgets: conftest's
fuzz_settings (fixed and derandomised; ``--fuzz-long`` for a long hunt).
"""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from elastic_pm_dyn.cli import main
from elastic_pm_dyn.errors import InputError, ModelError
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.sim.torque import load_torque_csv

CONFIG = Path(__file__).resolve().parent.parent / "config"
MODELS = {name: (CONFIG / f"{name}.yaml").read_bytes() for name in ("five_bar", "five_bar_vertical", "triglide")}
ACTIVE = ["left_motor", "right_motor"]

GARBAGE_VALUES = [
    b"", b"~", b"no", b"yes", b"off", b"1.5", b"-1", b"0", b"1e308", b"-1e308", b"1e999", b".nan", b".inf",
    b"-.inf", b"!kg 1", b"!!float abc", b"!!int 1.5", b"!!binary AAAA", b"!!python/object:os.system x",
    b"[1, 2]", b"[]", b"{a: 1}", b"{}", b"*undefined", b"&a [*a]", b"'0.6'", b"9" * 400, b"0x10", b"0o17",
    b"2001-12-14", b"true", b"\"\\u0000\"", b"|\n  text", b">", b"? complex", b"- x", b"1_000", b"'\xff'",
]


def _lines(data: bytes) -> list[bytes]:
    return data.split(b"\n")


def run_main(argv: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    """``elastic-pm-dyn argv`` in-process: (exit code, stdout, stderr with every warning as one
    more line, as a user would see it); argparse's SystemExit taken as its code."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: a value that is no number
            code = exc.code
    out, err = capsys.readouterr()
    return code, out, err + "".join(f"{w.category.__name__}: {w.message}\n" for w in caught)


@st.composite
def mutated_model(draw: st.DrawFn) -> bytes:
    """A shipped model with one to three mutations."""
    data = MODELS[draw(st.sampled_from(sorted(MODELS)))]
    for _ in range(draw(st.integers(1, 3))):
        lines = _lines(data)
        k = draw(st.integers(0, len(lines) - 1))
        kind = draw(st.sampled_from(["delete", "duplicate", "value", "indent", "bytes", "truncate", "alias"]))
        if kind == "delete":
            del lines[k]
        elif kind == "duplicate":
            lines.insert(k, lines[k])
        elif kind == "value" and b":" in lines[k]:
            key = lines[k].split(b":", 1)[0]
            lines[k] = key + b": " + draw(st.sampled_from(GARBAGE_VALUES))
        elif kind == "indent":
            lines[k] = b" " * draw(st.integers(0, 12)) + lines[k].lstrip()
        elif kind == "bytes":
            pos = draw(st.integers(0, len(lines[k])))
            lines[k] = lines[k][:pos] + draw(st.binary(min_size=1, max_size=8)) + lines[k][pos:]
        elif kind == "truncate":
            lines = lines[:k] + [lines[k][:draw(st.integers(0, len(lines[k])))]]
        elif kind == "alias":  # an anchor on one value, its alias in place of another
            j = draw(st.integers(0, len(lines) - 1))
            if b": " in lines[k] and b": " in lines[j]:
                lines[k] = lines[k].replace(b": ", b": &x ", 1)
                key = lines[j].split(b":", 1)[0]
                lines[j] = key + b": *x"
        data = b"\n".join(lines)
    return data


def _assert_one_line(message: str, limit: int = 600) -> None:
    assert message and "\n" not in message and len(message) <= limit, message[:3000]


@fuzz_settings(400)
@given(data=mutated_model())
def test_mutated_model_loads_or_raises_one_model_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "model.yaml"
        p.write_bytes(data)
        try:
            load_model(p)
        except ModelError as err:
            _assert_one_line(str(err))
            assert str(err).startswith(str(p)), str(err)


@fuzz_settings(15)
@given(data=mutated_model())
def test_check_of_a_mutated_model_exits_0_or_2_with_one_line(data: bytes, capsys: pytest.CaptureFixture) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "model.yaml"
        p.write_bytes(data)
        cwd = os.getcwd()
        os.chdir(tmp)  # anything written would land here
        try:
            with warnings.catch_warnings(record=True) as caught:  # each would be a line more on stderr
                warnings.simplefilter("always")
                code = main(["check", str(p)])
        finally:
            os.chdir(cwd)
        err = capsys.readouterr().err + "".join(f"{w.category.__name__}: {w.message}\n" for w in caught)
        assert os.listdir(tmp) == ["model.yaml"]
    assert code in (0, 2), err
    if code == 2:
        assert err.count("\n") == 1 and "Traceback" not in err, err[:3000]
    else:
        assert err == ""


# ---------------------------------------------------------------- torque CSVs
CELLS = [b"0", b"1e-3", b"-0.5", b"nan", b"inf", b"-inf", b"1e400", b"", b"x", b"1,2", b"\"3\"", b"\x00", b"\xff",
         b"left_motor", b"t", b"#", b" 2 ", b"1_0", b"0x1p-3"]


@st.composite
def mutated_csv(draw: st.DrawFn) -> bytes:
    n = draw(st.integers(1, 6))
    names = list(draw(st.permutations(ACTIVE)))
    rows = [b",".join([b"t", *(n.encode() for n in names)])]
    rows += [b"%g,%g,%g" % (k * 1e-3, np.sin(k), np.cos(k)) for k in range(n)]
    for _ in range(draw(st.integers(1, 3))):
        r = draw(st.integers(0, len(rows) - 1))
        cells = rows[r].split(b",")
        c = draw(st.integers(0, len(cells) - 1))
        kind = draw(st.sampled_from(["cell", "drop_cell", "add_cell", "drop_row", "dup_row", "bytes", "swap"]))
        if kind == "cell":
            cells[c] = draw(st.sampled_from(CELLS))
        elif kind == "drop_cell":
            del cells[c]
        elif kind == "add_cell":
            cells.insert(c, draw(st.sampled_from(CELLS)))
        elif kind == "bytes":
            cells[c] += draw(st.binary(min_size=1, max_size=6))
        rows[r] = b",".join(cells)
        if kind == "drop_row" and len(rows) > 1:
            del rows[r]
        elif kind == "dup_row":
            rows.insert(r, rows[r])
        elif kind == "swap" and len(rows) > 2:
            rows[1], rows[-1] = rows[-1], rows[1]
    return b"\n".join(rows) + draw(st.sampled_from([b"\n", b"", b"\r\n"]))


@fuzz_settings(300)
@given(data=mutated_csv())
def test_mutated_torque_csv_loads_or_raises_one_input_error(data: bytes) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "tau.csv"
        p.write_bytes(data)
        try:
            table = load_torque_csv(p, ACTIVE)
        except InputError as err:
            _assert_one_line(str(err))
            assert str(err).startswith(str(p)), str(err)
        else:
            assert np.all(np.diff(table.times) > 0) and np.all(np.isfinite(table.values))


# ---------------------------------------------------------------- simulate's flags
NUMBERS = ["nan", "NaN", "inf", "-inf", "-1", "0", "-0.0", "1e300", "1e-300", "5e-324", "1e-3", "2e-4", "text",
           "", "0x10", "1e", "--"]


@fuzz_settings(25)
@given(flag=st.sampled_from(["--duration", "--dt", "--sample", "--rtol", "--atol"]), value=st.sampled_from(NUMBERS),
       integrator=st.sampled_from(["rk4", "dop853"]))
def test_simulate_flags_exit_0_or_2_with_one_line(flag: str, value: str, integrator: str,
                                                   capsys: pytest.CaptureFixture) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tau = Path(tmp) / "tau.csv"
        tau.write_text("t,left_motor,right_motor\n0,0.02,-0.01\n")
        out = Path(tmp) / "run.csv"
        args = {"--duration": "0.004", "--sample": "1e-3", "--integrator": integrator}
        args[flag] = value
        argv = ["simulate", "--model", str(CONFIG / "five_bar.yaml"), "--torques", str(tau), "--out", str(out)]
        argv += [f"{k}={v}" for k, v in args.items()]
        code, _, err = run_main(argv, capsys)
        written = out.exists()
    assert code in (0, 2), err
    if code == 2:
        assert err.count("\n") == 1 and "Traceback" not in err, err[:3000]
        assert not written
    else:
        assert written and err == ""
