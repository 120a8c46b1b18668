"""Which format a model file is in, and the URDF / MJCF route to a :class:`Model`."""

from __future__ import annotations

from pathlib import Path

from elastic_pm_dyn.errors import ModelError
from elastic_pm_dyn.model.closures_sidecar import SIDECAR_NAME, find_sidecar, read_sidecar
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.model.xml_source import is_xml

YAML, URDF, MJCF, SDF = "yaml", "urdf", "mjcf", "sdf"
_SUFFIXES = {".yaml": YAML, ".yml": YAML, ".urdf": URDF, ".mjcf": MJCF, ".sdf": SDF}
_ROOTS = {"robot": URDF, "mujoco": MJCF, "sdf": SDF}


def model_format(path: str | Path) -> str:
    """``yaml``, ``urdf`` or ``mjcf``: by suffix, else (``.xml`` and the rest) by the XML root."""
    suffix = Path(path).suffix.lower()
    if suffix in _SUFFIXES:
        return _SUFFIXES[suffix]
    root = is_xml(path)
    if root is None:
        if suffix == ".xml":
            raise ModelError(str(path), "", "not an XML file (expected a <robot> URDF, a <mujoco> MJCF or an <sdf>)")
        return YAML  # a model YAML under any other name; its reader reports what is wrong
    if root not in _ROOTS:
        raise ModelError(str(path), "", f"an XML file with root <{root}>: expected <robot> (URDF), <mujoco> (MJCF) "
                         "or <sdf> (SDFormat)")
    return _ROOTS[root]


def read_robot_file(path: str | Path, kind: str, closures: str | Path | None = None,
                    fix_base: bool = False, servos_as_motors: bool = False, closure_tol: float | None = None) -> Model:
    from elastic_pm_dyn.model.from_tree import build_model
    from elastic_pm_dyn.model.loose_closures import CLOSURE_TOL
    tol = CLOSURE_TOL if closure_tol is None else closure_tol
    if kind == URDF:
        from elastic_pm_dyn.model.urdf import read_urdf
        tree = read_urdf(path)
        sidecar_path = Path(closures) if closures is not None else find_sidecar(path)
        if sidecar_path is None:
            raise ModelError(str(path), "", f"a URDF needs its loop closures and motors: a {SIDECAR_NAME} next to it "
                             "or a closures file (closed_loop, type, name_mot)")
        return build_model(tree, read_sidecar(sidecar_path), tol)
    if kind == SDF:
        from dataclasses import replace

        from elastic_pm_dyn.model.sdf import read_sdf
        tree = read_sdf(path)
        sidecar_path = Path(closures) if closures is not None else find_sidecar(path)
        sidecar = read_sidecar(sidecar_path) if sidecar_path is not None else None
        if sidecar is not None and sidecar.motors:  # the sidecar names the motors: not Drake's efforts
            tree.joints = [replace(j, actuated=False) for j in tree.joints]
        return build_model(tree, sidecar, tol)
    from elastic_pm_dyn.model.mjcf import read_mjcf
    if closures is not None:
        raise ModelError(str(closures), "", f"an MJCF holds its own closures (<equality>); no sidecar for {path}")
    return build_model(read_mjcf(path, fix_base, servos_as_motors), None, tol)
