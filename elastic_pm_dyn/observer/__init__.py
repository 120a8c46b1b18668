"""State observer: an EKF over the exact SCDD model (elastic deflections, branch forces).

ROS-free: :class:`~elastic_pm_dyn.observer.schedule.ekf.Observer` is driven by plain arrays, by the
offline command (``elastic-pm-dyn observe``) and by the plant node in ``mode: observer``.
"""

from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.observer.schedule.ekf import Estimate, Observer, ObserverFault, UpdateResult

__all__ = ["Estimate", "Observer", "ObserverConfig", "ObserverFault", "UpdateResult", "load_config"]
