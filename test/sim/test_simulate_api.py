"""``epd.simulate``: the simulator's run from a model and torques in any accepted form, and the
command line's CSV when ``out`` is given."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import elastic_pm_dyn as epd

MODEL = Path(__file__).resolve().parents[2] / "config" / "five_bar.yaml"
TORQUE = [0.3, -0.2]  # [N m] per motor: enough to move the five-bar visibly in 20 ms
DURATION = 0.02  # [s]


@pytest.fixture(scope="module")
def mech() -> epd.Mechanism:
    return epd.Mechanism(epd.load_model(MODEL))


@pytest.fixture(scope="module")
def reference(mech: epd.Mechanism):
    """What a user writes without epd.simulate."""
    return epd.Simulator(mech, epd.SimulationOptions()).run(epd.ConstantTorque(np.array(TORQUE)), DURATION)


def _same(a, b) -> None:
    for name in ("t", "q", "qd", "tau"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_equals_the_simulator_bit_for_bit_whatever_form_the_model_takes(mech, reference) -> None:
    assert np.ptp(reference.q[:, mech.active]) > 1e-4  # [rad]: the run moves, the comparison means something
    for model in (MODEL, str(MODEL), epd.load_model(MODEL), mech):
        _same(epd.simulate(model, TORQUE, DURATION), reference)
    _same(epd.simulate(mech, epd.ConstantTorque(np.array(TORQUE)), DURATION), reference)
    # a function is refitted per step (a smooth source): the same motion, not the same bits
    by_function = epd.simulate(mech, lambda t: np.array(TORQUE), DURATION)
    assert np.array_equal(by_function.tau, reference.tau)
    assert np.allclose(by_function.q, reference.q, rtol=0.0, atol=1e-9)


def test_options_as_an_object_or_keywords(mech) -> None:
    options = epd.SimulationOptions(integrator="dop853", sample=5e-3)
    a = epd.simulate(mech, TORQUE, DURATION, options=options)
    b = epd.simulate(mech, TORQUE, DURATION, integrator="dop853", sample=5e-3)
    _same(a, b)
    assert len(a.t) == 5  # 0, 5, 10, 15, 20 ms
    with pytest.raises(epd.InputError, match="not both"):
        epd.simulate(mech, TORQUE, DURATION, options=options, sample=1e-3)
    with pytest.raises(epd.InputError, match="unknown simulation option 'samples'"):
        epd.simulate(mech, TORQUE, DURATION, samples=1e-3)


def test_out_writes_the_bytes_the_command_line_writes(mech, reference, tmp_path: Path) -> None:
    torques = tmp_path / "tau.csv"
    times = np.arange(0.0, DURATION, 1e-3)  # a table stepping at 1 kHz, as a controller sends it
    steps = np.column_stack([times, 0.3 * np.cos(80 * times), -0.2 + 0.1 * np.sin(50 * times)])
    np.savetxt(torques, steps, delimiter=",", header="t," + ",".join(mech.active_names), comments="")
    cli = tmp_path / "cli.csv"
    proc = subprocess.run([sys.executable, "-m", "elastic_pm_dyn", "simulate", "--model", str(MODEL),
                           "--torques", str(torques), "--duration", str(DURATION), "--out", str(cli)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    result = epd.simulate(MODEL, torques, DURATION, tmp_path / "api.csv")
    assert (tmp_path / "api.csv").read_bytes() == cli.read_bytes()
    assert result.tau[1, 0] == pytest.approx(0.3 * np.cos(80 * 1e-3))  # the table was read, held per sample
    table = epd.load_torque_csv(torques, mech.active_names)
    _same(result, epd.Simulator(mech).run(table, DURATION))


@pytest.mark.parametrize(("torques", "match"), [
    ([0.1, 0.2, 0.3], r"3 values per sample, but five_bar has 2 motors"),
    (np.zeros((2, 2)), r"a constant torque is 2 numbers"),
    ("no_such_file.csv", r"no_such_file\.csv"),
    ("text", r"text"),
])
def test_bad_torques_are_one_line_input_errors(mech, torques, match: str) -> None:
    with pytest.raises(epd.InputError, match=match) as err:
        epd.simulate(mech, torques, DURATION)
    assert "\n" not in str(err.value)


def test_bad_model_or_duration_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(epd.ModelError, match=r"missing\.yaml") as err:
        epd.simulate(tmp_path / "missing.yaml", TORQUE, DURATION)
    assert "\n" not in str(err.value)
    with pytest.raises(epd.InputError, match="duration must be a positive number"):
        epd.simulate(MODEL, TORQUE, -1.0)
