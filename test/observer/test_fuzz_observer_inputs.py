"""Property: the observer's configuration, ``--set``, numeric CLI flags and output paths
end in a result or one line (issue #23 item 7).

Observer parameters of every name, given values of the right and the wrong type (NaN, Inf,
huge and negative numbers, text, nested lists and maps) and unknown names, through
``ObserverConfig.from_parameters``, ``with_overrides`` and ``load_config`` of a written
file: a valid configuration or one one-line InputError naming the parameter. ``observe``
and ``tune`` ``--set NAME=VALUE`` with arbitrary text, YAML-ish values, deep nesting and
aliases, numeric flags of the main subcommands, and output paths (existing files and
folders, missing parents, spaces, unicode, over-long names) through
``elastic_pm_dyn.cli.main``: exit 0 with complete output, or exit 2 with one line and
nothing half-written. The filter itself never runs here (the commands stop at a model
that does not exist, or at a bag named ``none``). Budgets: conftest's fuzz_settings.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import pytest
import yaml
from conftest import fuzz_settings
from hypothesis import example, given
from hypothesis import strategies as st
from test_fuzz_inputs import run_main

from elastic_pm_dyn.cli import MAX_MESSAGE
from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.observer.config import DEFAULT_PARAMETERS, PREFIX, ObserverConfig, load_config

CONFIG = Path(__file__).resolve().parents[1].parent / "config"
FIVE_BAR = CONFIG / "five_bar.yaml"
NAMES = sorted(DEFAULT_PARAMETERS)


def _assert_one_line(message: str, limit: int = 600) -> None:
    assert message and "\n" not in message and len(message) <= limit, message[:3000]


# ---------------------------------------------------------------- values
SPECIAL_FLOATS = [math.nan, math.inf, -math.inf, 0.0, -0.0, 1e308, -1e308, 5e-324, 1e-12, -1.0, 1e300]
scalars = st.one_of(
    st.sampled_from(SPECIAL_FLOATS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(10 ** 400), max_value=10 ** 400),
    st.sampled_from([0, 1, 2, 4, -1, 10 ** 18, 2 ** 63, 10 ** 400]),
    st.booleans(),
    st.none(),
    st.text(max_size=12),
    st.sampled_from(["active", "all", "none", "encoders", "imu", "branch_forces", "etd2", "rk4", "x", "y", "z",
                     "band_limited", "measurement", "model", "auto", "", "\n", "a\nb"]),
)
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                      max_leaves=8)
# a value of the parameter's own type, near and beyond its valid range, or any value at all
def _typed(name: str) -> st.SearchStrategy:
    default = DEFAULT_PARAMETERS[name]
    if isinstance(default, bool):
        return st.booleans()
    if isinstance(default, float):
        return st.one_of(st.sampled_from(SPECIAL_FLOATS), st.floats(), st.integers(-10, 10 ** 6))
    if isinstance(default, int):
        return st.integers(-5, 10 ** 6)
    if isinstance(default, str):
        return st.one_of(st.just(default), st.text(max_size=12))
    if isinstance(default[0], float):
        return st.lists(st.one_of(st.sampled_from(SPECIAL_FLOATS), st.floats()), max_size=5)
    return st.lists(st.sampled_from(["active", "elastic", "passive", "all", "none", "encoders", "imu", "x", "y",
                                     "z", "left_motor", ""]), max_size=4)


@st.composite
def parameters(draw: st.DrawFn) -> dict:
    """A few known parameters (sometimes with the ``observer.`` prefix), maybe an unknown one."""
    out = {}
    for name in draw(st.lists(st.sampled_from(NAMES), min_size=1, max_size=4, unique=True)):
        value = draw(st.one_of(_typed(name), values) if draw(st.booleans()) else _typed(name))
        out[(PREFIX + name) if draw(st.booleans()) else name] = value
    if draw(st.integers(0, 9)) == 0:
        out[draw(st.one_of(st.text(max_size=20), st.sampled_from(["process", "observer.", "gating.x", "Sensors"])))] \
            = draw(values)
    return out


def _names_a_parameter(message: str, given: dict) -> bool:
    keys = [k.removeprefix(PREFIX) for k in given]
    return "unknown observer parameter" in message or any(
        k.rsplit(".", 1)[-1] in message or (PREFIX + k.split(".", 1)[0]) in message for k in keys)


@fuzz_settings(300)
@given(params=parameters())
@example(params={"process.dt": 10 ** 400})
@example(params={"imu.stddev": [1.0, 10 ** 400]})
@example(params={"process.disturbance_bandwidth": list(range(10_000))[::-1]})
@example(params={"observer.unknown\nname": 1})
def test_observer_parameters_give_a_config_or_one_input_error(params: dict) -> None:
    try:
        cfg = ObserverConfig.from_parameters(params, "<fuzz>")
    except InputError as err:
        _assert_one_line(str(err))
        assert str(err).startswith("<fuzz>: ") and _names_a_parameter(str(err), params), str(err)
    else:
        assert set(cfg.parameters) == set(DEFAULT_PARAMETERS)
        assert cfg.process.max_interval > 0 and cfg.command_delay >= 0 and cfg.process.dt >= 0


@fuzz_settings(150)
@given(params=parameters())
def test_with_overrides_gives_a_config_or_one_input_error(params: dict) -> None:
    base = ObserverConfig.from_parameters({}, "<base>")
    flat = {k.removeprefix(PREFIX).replace(".", "__"): v for k, v in params.items()}
    try:
        cfg = base.with_overrides(**flat)
    except InputError as err:
        _assert_one_line(str(err))
        assert str(err).startswith("<base>: ") and _names_a_parameter(str(err), params), str(err)
    else:
        for k, v in params.items():
            key = k.removeprefix(PREFIX)
            if isinstance(v, float) and not isinstance(DEFAULT_PARAMETERS.get(key), list):
                assert cfg.parameters[key] == v or (v != v and cfg.parameters[key] != cfg.parameters[key])


def _tree(flat: dict) -> dict:
    """Dotted names -> nested maps (as a parameter file holds them); a clash keeps the first."""
    root: dict = {}
    for name, value in flat.items():
        node = root
        *parents, leaf = name.removeprefix(PREFIX).split(".")
        for p in parents:
            nxt = node.setdefault(p, {})
            if not isinstance(nxt, dict):
                break
            node = nxt
        else:
            node.setdefault(leaf, value)
    return root


@fuzz_settings(120)
@given(params=parameters(), layout=st.sampled_from(["node", "wildcard", "plain", "two_nodes", "list", "scalar",
                                                     "observer_scalar", "no_observer"]))
def test_load_config_of_a_written_file_gives_a_config_or_one_input_error(params: dict, layout: str) -> None:
    tree = _tree(params)
    doc = {"node": {"observer_node": {"ros__parameters": {"observer": tree}}},
           "wildcard": {"/**": {"ros__parameters": {"observer": tree, "model": "x.yaml"}}},
           "plain": {"observer": tree},
           "two_nodes": {"plant": {"ros__parameters": {"dt": 1e-4}},
                         "observer": {"ros__parameters": {"observer": tree}}},
           "list": [tree],
           "scalar": 3,
           "observer_scalar": {"n": {"ros__parameters": {"observer": 1.5}}},
           "no_observer": {"n": {"ros__parameters": tree}}}[layout]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "observer config.yaml"
        path.write_text(yaml.safe_dump(doc, allow_unicode=True))
        try:
            cfg = load_config(path)
        except InputError as err:
            _assert_one_line(str(err))
            assert str(err).startswith(str(path)), str(err)
        else:
            assert cfg.source == str(path)


# ---------------------------------------------------------------- --set through the CLI
YAMLISH = ["", "~", "null", "1e-4", "5e-5", "-1", "0", "1e308", "1e999", ".nan", ".inf", "-.inf", "nan", "9" * 400,
           "0x10", "0o17", "1_000", "true", "off", "[1, 2]", "[]", "{a: 1}", "{}", "[active]", "[encoders, imu]",
           "&a [*a]", "&a 1", "*a", "!!float abc", "!!int 1.5", "!!binary AAAA", "!!python/object:os.system x",
           "'0.6'", "\"\\u0000\"", "|\n  text", "? x", "- x", "[x, y]", "{process: {dt: 1}}", "a: 1\na: 2",
           "[1e-4, .inf]", "\t", "2001-12-14", "!kg 1", "[[1]]", "\"" * 3]


@st.composite
def set_items(draw: st.DrawFn) -> str:
    name = draw(st.one_of(st.sampled_from(NAMES), st.sampled_from([PREFIX + n for n in NAMES]),
                          st.sampled_from(["", "observer.", "process", "unknown", " process.dt ", "a=b"]),
                          st.text(max_size=15)))
    kind = draw(st.sampled_from(["yamlish", "text", "nest", "map_nest", "bomb", "no_sep"]))
    if kind == "yamlish":
        value = draw(st.sampled_from(YAMLISH))
    elif kind == "text":
        value = draw(st.text(max_size=40))
    elif kind == "nest":
        n = draw(st.sampled_from([1, 30, 63, 64, 65, 200, 6000]))
        value = "[" * n + draw(st.sampled_from(["1", "", "1e-4", "x"])) + "]" * n
    elif kind == "map_nest":
        n = draw(st.sampled_from([2, 64, 5000]))
        value = "{a: " * n + "1" + "}" * n
    elif kind == "bomb":
        levels = draw(st.integers(1, 9))
        parts = ["&a0 [x, x, x, x, x, x, x, x, x]"]
        value = "{" + ", ".join([f"a0: {parts[0]}"] + [f"a{k}: &a{k} [" + ", ".join([f"*a{k - 1}"] * 9) + "]"
                                                       for k in range(1, levels)]) + "}"
    else:
        return name
    return f"{name}={value}"


def _assert_error_line(err: str) -> str:
    assert err.count("\n") == 1 and "Traceback" not in err, err[:3000]
    assert err.startswith("elastic-pm-dyn") and len(err) <= MAX_MESSAGE + 120, err[:3000]
    return err


@fuzz_settings(60)
@given(items=st.lists(set_items(), min_size=1, max_size=3), command=st.sampled_from(["observe", "tune"]))
@example(items=["process.dt=" + "[" * 5000 + "]" * 5000], command="observe")
@example(items=["process.dt=" + "9" * 400], command="observe")
@example(items=["imu.stddev=[1, " + "9" * 400 + "]"], command="tune")
@example(items=["branch_forces.branches=!!int 1.5"], command="observe")  # a ValueError traceback before
@example(items=["process.dt=!!float abc"], command="tune")
def test_set_values_are_accepted_or_one_line(items: list[str], command: str, capsys: pytest.CaptureFixture) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "missing.yaml"  # an accepted configuration stops at the model, before any work
        argv = [command, "--model", str(model), "--bag", "none", "--out", str(Path(tmp) / "out")]
        argv += [f"--set={item}" for item in items]
        code, _, err = run_main(argv, capsys)
        assert os.listdir(tmp) == []
    assert code == 2, err
    _assert_error_line(err)


# ---------------------------------------------------------------- numeric flags
# valid values are kept small: a valid feedforward runs (1e-3 s move x 1e9 Hz is refused before work, 2 s is cheap)
NUMBERS = ["nan", "NaN", "inf", "-inf", "-1", "0", "-0.0", "1e300", "1e-300", "5e-324", "1e-3", "0.5", "2", "1e9",
           "text", "", "0x10", "1e", "--", "1_0", "9" * 400]
FLAGS = [  # (argv before the flag, flags, whether a valid value may start real work)
    (["feedforward", "--model", str(FIVE_BAR), "--hold", "0.05"], ["--move", "--rate"]),
    (["feedforward", "--model", str(FIVE_BAR), "--move", "0.05"], ["--hold", "--rate"]),
    (["analyze", "none", "--no-plots"], ["--hold-start", "--max-samples", "--window-samples"]),
    (["tune", "--model", "MISSING", "--bag", "none"], ["--threads", "--seconds", "--max-evaluations"]),
    (["observe", "--model", "MISSING", "--bag", "none"], ["--set=process.dt", "--set=command_delay",
                                                           "--set=process.max_interval", "--set=gating.nis_window"]),
    (["simulate", "--model", str(FIVE_BAR), "--torques", "TAU", "--duration", "0.004"], ["--duration", "--dt",
                                                                                         "--sample"]),
    (["ros-demo"], ["--duration"]),  # only with --observer: refused before anything starts
]


@fuzz_settings(40)
@given(case=st.sampled_from(FLAGS), data=st.data())
@example(case=FLAGS[0], data={"--move": "1e-12"})  # explicit examples: the flags' values as given
@example(case=FLAGS[0], data={"--move": "--"})  # argparse handed [] to the command: a traceback before
@example(case=FLAGS[2], data={"--hold-start": "--"})
@example(case=FLAGS[3], data={"--threads": "--"})
def test_numeric_flags_exit_0_or_2_with_one_line(case: tuple, data, capsys: pytest.CaptureFixture) -> None:
    head, flags = case
    if isinstance(data, dict):
        chosen = data
    else:
        values = st.sampled_from(NUMBERS)
        if head[0] not in ("feedforward", "simulate"):  # (valid values compute: they stay in NUMBERS)
            values = st.one_of(values, st.floats().map(repr), st.integers(-10 ** 20, 10 ** 20).map(str))
        chosen = {f: data.draw(values, label=f)
                  for f in data.draw(st.lists(st.sampled_from(flags), min_size=1, max_size=2, unique=True))}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.csv"
        tau = Path(tmp) / "tau.csv"
        tau.write_text("t,left_motor,right_motor\n0,0.02,-0.01\n")
        argv = [str(Path(tmp) / "missing.yaml") if a == "MISSING" else str(tau) if a == "TAU" else a for a in head]
        argv += ["--out", str(out)]
        argv += [f"{f}={v}" for f, v in chosen.items()]
        cwd = os.getcwd()
        os.chdir(tmp)  # anything written elsewhere would land here
        try:
            code, _, err = run_main(argv, capsys)
        finally:
            os.chdir(cwd)
        left = sorted(os.listdir(tmp))
    assert code in (0, 2) or (code == 1 and head[0] == "simulate"), err[:3000]
    if code == 1:  # a run that blew up: its partial output kept and said so, then the error (documented)
        assert "Traceback" not in err and err.count("\n") <= 2 and "partial output" in err, err[:3000]
        assert left == ["out.csv", "tau.csv"], left
    elif code == 2:
        _assert_error_line(err)
        assert left == ["tau.csv"], left
    else:
        assert left == ["out.csv", "tau.csv"] and err == "", (left, err)


# ---------------------------------------------------------------- output paths
name_chars = st.characters(blacklist_categories=("Cs",), blacklist_characters="/\x00")
names = st.one_of(st.text(name_chars, min_size=1, max_size=30), st.sampled_from(
    ["out.csv", "with space.urdf", "ünïcødé ✓.csv", "-dash", ".hidden", " ", "x" * 255, "é" * 127, "é" * 128,
     "x" * 250 + ".csv", "x" * 256, "a\nb", "*?[]"])).filter(lambda n: n not in (".", ".."))


@st.composite
def output_case(draw: st.DrawFn) -> tuple[list[str], str]:
    """The path's components below the tmp folder, and what is there before the command runs."""
    parts = draw(st.lists(names, min_size=1, max_size=3))
    state = draw(st.sampled_from(["fresh", "fresh", "file", "dir", "parent_missing", "parent_is_file"]))
    if state in ("parent_missing", "parent_is_file") and len(parts) == 1:
        parts = ["sub", *parts]
    return parts, state


def _is_dir(path: Path) -> bool:
    try:
        return path.is_dir()
    except OSError:  # a name too long (Python 3.11 raises it)
        return False


def _tree_of(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None) for p in sorted(root.rglob("*"))}


@fuzz_settings(40)
@given(case=output_case(), command=st.sampled_from(["urdf", "urdf", "feedforward"]))
@example(case=(["x" * 250 + ".csv"], "fresh"), command="urdf")
@example(case=(["é" * 127], "file"), command="feedforward")
@example(case=(["out"], "dir"), command="urdf")
def test_output_paths_are_written_complete_or_refused_in_one_line(case: tuple, command: str,
                                                                  capsys: pytest.CaptureFixture) -> None:
    parts, state = case
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        out = root.joinpath(*parts)
        try:  # a name the file system refuses (too long) leaves the setting unmade: the command must say so
            if state in ("fresh", "file", "dir"):
                out.parent.mkdir(parents=True, exist_ok=True)
                if state == "file":
                    out.write_bytes(b"old content\n")
                elif state == "dir":
                    out.mkdir()
            elif state == "parent_is_file":
                out.parent.parent.mkdir(parents=True, exist_ok=True)
                out.parent.write_bytes(b"a file\n")
        except OSError:
            pass
        before = _tree_of(root)
        argv = (["urdf", str(FIVE_BAR)] if command == "urdf"
                else ["feedforward", "--model", str(FIVE_BAR), "--move", "0.02", "--hold", "0"]) + ["--out", str(out)]
        code, stdout, err = run_main(argv, capsys)
        after = _tree_of(root)
        writable = _is_dir(out.parent) and not _is_dir(out) and len(out.name.encode()) <= 255
        assert code == (0 if writable else 2), (code, err[:3000])
        if code == 0:
            assert err == "" and str(out) in stdout
            changed = {k for k in after if after[k] != before.get(k)} | {k for k in before if k not in after}
            assert changed == {str(out.relative_to(root))}, changed  # the output, nothing else (no temporary)
            text = out.read_text()
            if command == "urdf":
                assert text.rstrip().endswith("</robot>")
            else:
                rows = text.splitlines()
                assert rows[0] == "t,left_motor,right_motor" and len(rows) - 1 == int(stdout.split()[0])
        else:
            _assert_error_line(err)
            shown = " ".join(err.split())
            assert (" ".join(str(out).split()) in shown or repr(str(out))[1:-1] in shown
                    or len(str(out)) > 300), err  # a long path may be cut at MAX_MESSAGE
            assert after == before  # nothing written, nothing destroyed
