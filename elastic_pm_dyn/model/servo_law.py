"""MuJoCo's actuator law on a servo's motor, as the machine's own terms.

A servo with a fixed gain and an affine bias (``<position>``: gain kp, bias (0, -kp, -kv);
``<velocity>``: gain kv, bias (0, 0, -kv); ``<general>`` with ``biastype="affine"``) pushes
with f = gain ctrl + b0 + b1 L + b2 dL/dt along its length L = gear (w q + L_c) (w its moment
arm in the independent coordinates: 1 on its own joint, a fixed tendon's work through the
couplings; L_c the couplings' constant), the joints feeling gear w f. Where w acts on the
motor's own coordinate only, that is exactly: a spring of stiffness -b1 gear^2 w^2 on the motor
(its rest where the constant part balances it), a viscous friction -b2 gear^2 w^2, and the input
ctrl reaching the joint as gear gain w ctrl (a column of the transmission B). The ctrl range
clamps the input (:attr:`Model.input_ranges`); the force range clamps f in the dynamics
(:attr:`Joint.force_range`, as MuJoCo clamps it), where w is the motor's coordinate alone.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from elastic_pm_dyn.model.description import PASSIVE, Model
from elastic_pm_dyn.model.kinematic_tree import ServoLaw

ARM_TOL = 1e-12  # a moment arm below this on a coordinate is none


def with_servo_laws(model: Model, servos: list[ServoLaw]) -> Model:
    """``model`` with each servo's law on its motor (module doc); one line for a law it cannot hold."""
    if not servos:
        return model
    names = model.joint_names
    active = model.active_names
    B = model.transmission()
    joints = {j.name: j for j in model.joints}
    transmissions = dict(model.transmissions)
    ranges = list(model.input_ranges)
    for s in servos:
        w = B[:, active.index(s.joint)]  # generalised force per unit force along L / gear
        a = names.index(s.joint)
        others = [names[i] for i in np.flatnonzero(np.abs(w) > ARM_TOL) if i != a]
        if others and (s.bias[1] or s.bias[2]):
            raise s.where.error(f"not supported yet: a servo whose bias acts through its tendon on {', '.join(others)} "
                                f"besides {s.joint!r} (a spring across coordinates); servos_as_motors=True "
                                "(--servos-as-motors) takes its joint for a motor's, its law left out")
        g, wa = s.gear, float(w[a])
        k = -s.bias[1] * g * g * wa * wa
        c = -s.bias[2] * g * g * wa * wa
        if k < 0 or c < 0:
            raise s.where.error(f"a servo bias that pushes away (bias1 {s.bias[1]:g}, bias2 {s.bias[2]:g}: a negative "
                                "stiffness or damping) is no machine's; check its biasprm")
        const = g * wa * (s.bias[0] + s.bias[1] * g * _length_constant(model, s))  # the force at q = 0, qd = 0
        j = joints[s.joint]
        stiffness = j.stiffness + k
        if stiffness == 0.0 and const != 0.0:
            raise s.where.error(f"not supported yet: a servo bias of constant force ({const:g}) with no spring "
                                "to hold it (bias0 without bias1)")
        rest = (j.stiffness * j.rest + const) / stiffness if stiffness else j.rest
        clamp = None
        if s.forcerange is not None:
            if others:  # a tendon servo acting on several coordinates: no one joint's force to clamp
                warnings.warn(f"{s.where.file}:{s.where.line}: {s.where.element}: its force range is not applied (its "
                              f"tendon acts on {', '.join(others)} too)", stacklevel=3)
            else:  # the servo's own spring and damper, with the constant force they balance at its rest
                clamp = (g * wa, k, c, const / k if k else 0.0, *s.forcerange)
        joints[s.joint] = replace(j, stiffness=stiffness, rest=rest, friction=j.friction + c, force_range=clamp)
        transmissions[s.joint] = tuple((names[i], float(g * s.gain * w[i])) for i in np.flatnonzero(w))
        if s.ctrlrange is not None:
            ranges.append((s.joint, *s.ctrlrange))
    chains = tuple(replace(ch, joints=tuple(joints[j.name] for j in ch.joints)) for ch in model.chains)
    return replace(model, chains=chains, transmissions=tuple(transmissions.items()), input_ranges=tuple(ranges))


def _length_constant(model: Model, servo: ServoLaw) -> float:
    """L_c: the part of the length over ``gear`` that no coordinate carries, from the passive
    joints the couplings set (their value with every independent coordinate at zero)."""
    c = model.closure
    passive = [name for name, _ in servo.terms if model.joints[model.joint_index(name)].role == PASSIVE]
    if not passive or c is None or not c.couplings:
        return 0.0
    names = model.joint_names
    C = c.coupling_matrix(names)
    cols = [names.index(name) for name in passive]
    x0 = np.linalg.lstsq(C[:, cols], C[:, -1], rcond=None)[0]
    return float(sum(coef * x0[passive.index(name)] for name, coef in servo.terms if name in passive))
