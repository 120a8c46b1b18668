"""Model files: the reference five-bar as specified, and validation errors that point at the line."""

from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.loader import load_model, parse_model
from elastic_pm_dyn.model.yaml_source import YamlSource

CONFIG = Path(__file__).resolve().parents[1].parent / "config"


def test_five_bar_yaml_is_the_reference_machine() -> None:
    """Every number of docs/five_bar.md."""
    m = load_model(CONFIG / "five_bar.yaml")
    assert m.joint_names == ["left_motor", "left_spring", "left_elbow", "right_motor", "right_spring", "right_elbow"]
    assert [b.name for b in m.branches] == ["left", "right"]
    l1, l2, m1, me, m2, mee = 0.25, 0.35, 0.6, 0.3, 0.4, 0.2
    for chain, base in zip(m.chains, (-0.10, 0.10), strict=True):
        motor, spring, elbow = chain.joints
        assert (motor.role, spring.role, elbow.role) == ("active", "elastic", "passive")
        assert np.allclose(motor.origin_xyz, [base, 0, 0]) and np.allclose(motor.axis, [0, 0, 1])
        assert motor.rotor_inertia == 1.0e-4
        assert motor.body.mass == m1 and np.allclose(motor.body.com, [l1 / 2, 0, 0])
        assert motor.body.inertia[2, 2] == pytest.approx(m1 * l1**2 / 12, rel=1e-15)
        assert spring.type == "prismatic" and np.allclose(spring.axis, [1, 0, 0])
        assert np.allclose(spring.origin_xyz, [l1, 0, 0])
        assert spring.stiffness == 5.464e6 and spring.damping == 40.0
        assert spring.body.mass == me and np.allclose(spring.body.com, 0)
        # Forearm plus half of the end-effector point mass lumped at the chain end.
        assert elbow.body.mass == pytest.approx(m2 + mee / 2)
        com = (m2 * l2 / 2 + mee / 2 * l2) / (m2 + mee / 2)
        assert np.allclose(elbow.body.com, [com, 0, 0])
        izz = m2 * l2**2 / 12 + m2 * (l2 / 2 - com) ** 2 + mee / 2 * (l2 - com) ** 2
        assert elbow.body.inertia[2, 2] == pytest.approx(izz, rel=1e-12)
        assert np.allclose(chain.end_xyz, [l2, 0, 0])
    assert np.all(m.gravity == 0)
    vertical = load_model(CONFIG / "five_bar_vertical.yaml")
    assert np.allclose(vertical.gravity, [0, -9.81, 0])


BASE = """\
name: t
chains:
  - name: a
    joints:
      - name: j1
        type: revolute
        role: active
        body: {mass: 1.0, com: [0.1, 0, 0]}
"""


def _error(text: str) -> ModelError:
    with pytest.raises(ModelError) as exc:
        parse_model(YamlSource(text, "bad.yaml"))
    return exc.value


def test_minimal_serial_model_loads() -> None:
    assert parse_model(YamlSource(BASE, "ok.yaml")).joint_names == ["j1"]


@pytest.mark.parametrize(("text", "key", "line", "words"), [
    (BASE + "  - name: b\n   joints: [\n", "", 10, "malformed YAML"),
    (BASE.replace("role: active", "role: motorised"), "chains[0].joints[0].role", 7, "unknown value 'motorised'"),
    (BASE.replace("mass: 1.0", "mass: -2"), "chains[0].joints[0].body.mass", 8, "must be > 0"),
    (BASE.replace("com: [0.1, 0, 0]", "com: [0.1, 0, 0], inertia: {ixx: -1}"),
     "chains[0].joints[0].body.inertia", 8, "not positive"),
    (BASE.replace("com: [0.1, 0, 0]", "com: [0.1, 0, 0], inertia: {ixx: 1, iyy: 0.1, izz: 0.1}"),
     "chains[0].joints[0].body.inertia", 8, "triangle inequality"),
    (BASE + "closure: {chains: [a, nowhere]}\n", "closure.chains[1]", 9, "missing chain 'nowhere'"),
    (BASE.replace("type: revolute", "type: helical"), "chains[0].joints[0].type", 6, "unknown value"),
    (BASE + "colour: red\n", "colour", 9, "unknown key"),
    (BASE.replace("role: active", "role: elastic"), "chains[0].joints[0].stiffness", 5, "stiffness > 0"),
    (BASE + "initial_state: {active: {j2: 1.0}}\n", "initial_state.active.j2", 9, "not an active joint"),
    (BASE.replace("mass: 1.0", "mass: heavy"), "chains[0].joints[0].body.mass", 8, "expected a number"),
])
def test_errors_name_file_line_and_key(text: str, key: str, line: int, words: str) -> None:
    err = _error(text)
    message = str(err)
    assert message.startswith(f"bad.yaml:{line}: ")
    assert err.key_path == key
    assert words in message


def test_unreadable_file_is_a_model_error(tmp_path: Path) -> None:
    with pytest.raises(ModelError, match="cannot read"):
        load_model(tmp_path / "missing.yaml")


def test_closure_must_fix_the_passive_joints() -> None:
    text = (CONFIG / "five_bar.yaml").read_text().replace("components: [x, y]", "components: [x]")
    assert "passive joints" in str(_error(text))
