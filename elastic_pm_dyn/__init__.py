"""elastic_pm_dyn: dynamics of elastic parallel manipulators.

The numerical core (model, kinematics, dynamics, sim) never imports rclpy; the ROS
nodes in :mod:`elastic_pm_dyn.ros` are thin layers over it.

Equation numbers in docstrings refer to the seed paper, "Derivation and Calculation of
the Dynamics of Elastic Parallel Manipulators" (Stachera & Schumacher).
"""

from elastic_pm_dyn._numba_cache import configure as _configure_numba_cache

__version__ = "0.1.0"

_configure_numba_cache()
