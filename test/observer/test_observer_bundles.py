"""The observer kernels' bundles are plain tuples read by named positions (``state[ST_P]``): each
constant names the position of its field in the NamedTuple that documents the bundle (nothing
here compiles)."""

from __future__ import annotations

from elastic_pm_dyn.observer.core import kernels
from elastic_pm_dyn.observer.core.sensors import FastEncoderPlan

# the State's Qd (discrete process noise) would collide with qd (the rates): its constant says what it is
RENAMED = {("ST_", "Qd"): "ST_QD_NOISE"}


def test_every_field_constant_is_its_fields_position() -> None:
    for bundle, prefix in ((kernels.Fixed, "FX_"), (kernels.Process, "PR_"), (kernels.State, "ST_"),
                           (kernels.ImuModel, "IM_")):
        names = [RENAMED.get((prefix, f), prefix + f.upper()) for f in bundle._fields]
        assert [getattr(kernels, n) for n in names] == list(range(len(names))), bundle.__name__
        assert len({n for n in dir(kernels) if n.startswith(prefix)}) == len(names), bundle.__name__


def test_the_encoder_plan_carries_the_kernels_bundle() -> None:
    plan = FastEncoderPlan("idx", "H", "R", "js", "wrap", False)
    assert plan.bundle == tuple(kernels.EncoderPlan("H", "R", "js", "wrap")) and type(plan.bundle) is tuple
