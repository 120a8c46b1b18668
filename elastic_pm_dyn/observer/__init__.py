"""State observer: an EKF over the exact SCDD model (elastic deflections, branch forces).

ROS-free: :class:`~elastic_pm_dyn.observer.schedule.observer.Observer` is driven by plain arrays, by the
offline command (``elastic-pm-dyn observe``) and by the plant node in ``mode: observer``.
"""

from elastic_pm_dyn.observer.config import ObserverConfig, load_config
from elastic_pm_dyn.observer.core.ekf import ObserverFault
from elastic_pm_dyn.observer.core.estimate import Estimate
from elastic_pm_dyn.observer.schedule.observer import Observer
from elastic_pm_dyn.observer.schedule.sensor_stats import UpdateResult

__all__ = ["Estimate", "Observer", "ObserverConfig", "ObserverFault", "UpdateResult", "load_config"]
