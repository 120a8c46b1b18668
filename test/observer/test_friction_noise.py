"""The observer takes a joint's dry friction F as a known term with its own uncertainty: a white
force of PSD process.friction_noise F^2 on each q_ae joint with friction, beside the torque
noise (config.py, core/ekf.py); no friction, nothing added."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.kinematics.mechanism import Mechanism
from elastic_pm_dyn.model.loader import load_model
from elastic_pm_dyn.observer import ObserverConfig
from elastic_pm_dyn.observer.core.ekf import Ekf

ROOT = Path(__file__).resolve().parents[2]
ARM = ROOT / "test" / "robots" / "menagerie_style" / "arm.xml"


def _arm() -> Mechanism:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return Mechanism(load_model(ARM, servos_as_motors=True))


def _config(**params) -> ObserverConfig:
    p = {"sensors": ["encoders"], "initial.source": "model"}
    p.update({k.replace("__", "."): v for k, v in params.items()})
    return ObserverConfig.from_parameters(p)


def test_each_frictional_joint_gets_noise_in_proportion_to_its_friction():
    mech = _arm()
    friction = np.array([j.coulomb for j in mech.model.joints])  # 0.05, 0.03, 0.01 N m
    cfg = _config()
    ekf = Ekf(mech, cfg)
    pc = cfg.process
    assert pc.friction_noise == 1e-4  # the documented default
    np.testing.assert_allclose(ekf.psd_ae, pc.torque_noise_psd + 1e-4 * friction**2, rtol=1e-15)
    assert np.all(np.diff(ekf.psd_ae) < 0)  # more friction, more uncertainty
    off = Ekf(mech, _config(process__friction_noise=0.0))
    assert np.all(off.psd_ae == pc.torque_noise_psd)


def test_no_friction_no_friction_noise():
    mech = Mechanism(load_model(ROOT / "config" / "five_bar.yaml"))
    cfg = _config()
    assert np.array_equal(Ekf(mech, cfg).psd_ae, Ekf(mech, _config(process__friction_noise=0.0)).psd_ae)


def test_a_negative_friction_noise_is_refused():
    with pytest.raises(InputError, match=r"process\.friction_noise: must be >= 0"):
        _config(process__friction_noise=-1e-4).validate()
