"""What MuJoCo would do with an MJCF that this package's machine does not: one line per kind.

The reader takes the dynamics MuJoCo compiles (bodies, joints, springs, dampers, armature,
motors, closures, couplings); MuJoCo also enforces joint limits and tendon ranges, friction
loss, contacts, control and force ranges, actuator dynamics, gravity compensation and fluid
forces. Each kind present in the compiled model (and not disabled by the file's own
``<flag>``) is one warning line naming its elements, so that nothing a file says about the
motion is dropped without a word. Visuals, meshes, sensors, cameras and lights do not act on
the motion and are passed over.
"""

from __future__ import annotations

import numpy as np

from elastic_pm_dyn.model.description import dry_friction_law

MAX_NAMED = 6  # elements named in a line; the rest counted


def listed(items: list[str], limit: int = MAX_NAMED) -> str:
    """``a, b, c`` or ``a, b, ... (12 in all)``: a line stays short whatever the file holds."""
    if len(items) <= limit:
        return ", ".join(items)
    return f"{', '.join(items[:limit])}, ... ({len(items)} in all)"


def _range(lo: float, hi: float) -> str:
    return f"[{lo:.4g}, {hi:.4g}]"


def dropped_lines(m, mujoco, names: dict[str, list[str]], coupled_tendons: set[int], kept_laws: set[int],
                  ranged_motors: set[int] = frozenset()) -> list[str]:
    """The lines for the compiled model ``m``; ``names`` holds the joint, tendon, actuator and
    body names by index, ``coupled_tendons`` the tendons whose range became a coupling,
    ``kept_laws`` the actuators whose law (gain, bias, ranges) is in the machine,
    ``ranged_motors`` the plain motors whose ranges clamp their inputs."""
    off = int(m.opt.disableflags)
    bit = mujoco.mjtDisableBit
    joints, tendons, actuators, bodies = names["joint"], names["tendon"], names["actuator"], names["body"]
    out = []
    if not off & int(bit.mjDSBL_LIMIT):
        limited = [f"{joints[j]} {_range(*m.jnt_range[j])}" for j in range(m.njnt) if m.jnt_limited[j]]
        if limited:
            out.append(f"joint limits are not enforced (a limit is MuJoCo's one-sided constraint; here the joints "
                       f"move through them): {listed(limited)}")
        ranged = [f"{tendons[t]} {_range(*m.tendon_range[t])}" for t in range(m.ntendon)
                  if m.tendon_limited[t] and t not in coupled_tendons]
        if ranged:
            out.append(f"tendon ranges are not enforced (only a tight one is taken as a coupling): {listed(ranged)}")
    if not off & int(bit.mjDSBL_FRICTIONLOSS):
        dry = [f"{joints[m.dof_jntid[d]]} {m.dof_frictionloss[d]:.4g}" for d in range(m.nv) if m.dof_frictionloss[d]]
        if dry:
            out.append(f"friction loss is dry (Coulomb) friction, {dry_friction_law()} (MuJoCo's a soft constraint): "
                       f"{listed(list(dict.fromkeys(dry)))}")
        dry = [f"{tendons[t]} {m.tendon_frictionloss[t]:.4g}" for t in range(m.ntendon) if m.tendon_frictionloss[t]]
        if dry:
            out.append(f"tendon friction loss is left out: {listed(dry)}")
    servos = [actuators[a] for a in range(m.nu) if a not in kept_laws and
              (m.actuator_gaintype[a] != 0 or m.actuator_biastype[a] != 0 or m.actuator_gainprm[a, 0] != 1.0)]
    if servos:
        out.append(f"the servos' law (force = gain ctrl + bias0 + bias1 q + bias2 qd) is left out, their "
                   f"joints are motors whose torque is the input (servos_as_motors): {listed(servos)}")
    geared = [f"{actuators[a]} {m.actuator_gear[a, 0]:.4g}" for a in range(m.nu)
              if a not in kept_laws and m.actuator_gear[a, 0] != 1.0]
    if geared:
        out.append(f"motors' gear is not applied: their input is the joint's torque (the tendon's force), "
                   f"not MuJoCo's ctrl (torque = gear ctrl): {listed(geared)}")
    ctrl = [f"{actuators[a]} {_range(*m.actuator_ctrlrange[a])}" for a in range(m.nu)
            if m.actuator_ctrllimited[a] and a not in kept_laws | ranged_motors]
    if ctrl and not off & int(bit.mjDSBL_CLAMPCTRL):
        out.append(f"control ranges are not applied (inputs are not clamped): {listed(ctrl)}")
    force = [f"{actuators[a]} {_range(*m.actuator_forcerange[a])}" for a in range(m.nu)
             if m.actuator_forcelimited[a] and a not in kept_laws | ranged_motors]
    force += [f"joint {joints[j]} {_range(*m.jnt_actfrcrange[j])}" for j in range(m.njnt) if m.jnt_actfrclimited[j]]
    if force:
        out.append(f"actuator force ranges are not applied (forces are not clamped): {listed(force)}")
    dyn = [actuators[a] for a in range(m.nu) if m.actuator_dyntype[a] != 0]
    if dyn:
        out.append(f"actuator dynamics (filter, integrator, muscle activation) are left out, the input acts at "
                   f"once: {listed(dyn)}")
    if not off & int(bit.mjDSBL_GRAVITY):
        comp = [f"{bodies[b]} {m.body_gravcomp[b]:.4g}" for b in range(m.nbody) if m.body_gravcomp[b]]
        if comp:
            out.append(f"gravity compensation (gravcomp) is left out: gravity acts in full on {listed(comp)}")
    fluid = [f"{k} {v}" for k, v in (("density", m.opt.density), ("viscosity", m.opt.viscosity)) if v]
    fluid += [f"wind {np.asarray(m.opt.wind).tolist()}"] if np.any(m.opt.wind) else []
    if fluid:
        out.append(f"fluid forces are left out ({', '.join(fluid)})")
    if not off & int(bit.mjDSBL_CONTACT):
        touching = _colliding(m, mujoco)
        if touching:
            out.append(f"contacts are not simulated (bodies pass through each other): {listed(touching)}")
    inactive = [str(e) for e in range(m.neq) if not m.eq_active0[e]]
    if inactive:
        out.append(f"inactive equalities (active='false') are left out: #{listed(inactive)} in file order")
    return out


def _colliding(m, mujoco) -> list[str]:
    """Geom pairs MuJoCo may collide: explicit ``<pair>``s, and geoms of two bodies whose
    contype and conaffinity match, save those MuJoCo filters (one weld body; a weld body and
    its weld parent, the world excepted, unless filterparent is disabled)."""
    geom = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or f"geom{g}" for g in range(m.ngeom)]
    out = [f"pair {geom[m.pair_geom1[p]]}-{geom[m.pair_geom2[p]]}" for p in range(m.npair)]
    weld = np.asarray(m.body_weldid)[np.asarray(m.geom_bodyid)]
    weld_parent = np.asarray(m.body_weldid)[np.asarray(m.body_parentid)]
    filter_parent = not int(m.opt.disableflags) & int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    ct, ca = np.asarray(m.geom_contype), np.asarray(m.geom_conaffinity)
    for a in range(m.ngeom):
        for b in range(a + 1, m.ngeom):
            wa, wb = weld[a], weld[b]
            if wa == wb or (filter_parent and wa != 0 and wb != 0
                            and (wa == weld_parent[wb] or wb == weld_parent[wa])):
                continue
            if ct[a] & ca[b] or ct[b] & ca[a]:
                out.append(f"{geom[a]}-{geom[b]}")
    return out
