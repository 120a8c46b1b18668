"""Drive the five-bar into a 1e4 N/m wall 5 mm ahead and stop it there, with no force sensor: the
observer (encoders + accelerometer) estimates the wrench on the end effector, and the chi-square
test on that estimate stops the move. Run: ``python examples/contact_stop.py``.
"""

from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd
from elastic_pm_dyn.observer import Observer, ObserverConfig
from elastic_pm_dyn.observer.core.contact import ContactDetector
from elastic_pm_dyn.sim.plant import Plant
from elastic_pm_dyn.sim.sensors import EncoderSpec, ImuSpec, SensorModel, SensorSpec
from elastic_pm_dyn.sim.wrench import ExternalWrench, Wall

mech = epd.Mechanism(epd.load_model(Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"))
x, y = mech.end_effector(epd.initial_state(mech))
wall = Wall([x, y - 0.005, 0.0], [0.0, 1.0, 0.0], stiffness=1e4, damping=10.0)  # below the tool, facing it
plant = Plant(mech, epd.SimulationOptions(integrator="etd2"), 1e-3, start="static", wrench=ExternalWrench([wall]))
sensors = SensorModel(mech, SensorSpec(EncoderSpec(enabled=True), ImuSpec(enabled=True)))
obs = Observer(mech, ObserverConfig.from_parameters({"sensors": ["encoders", "imu"], "process.wrench": "random_walk",
                                                     "imu.sample_timing": "before_command"}))
detector, ref, touched, stopped = ContactDetector(obs.layout), plant.q[mech.active].copy(), None, None
for _ in range(150):
    t, motors = plant.t, plant.q[mech.active]
    obs.update_joint_states(t, mech.active_names, sensors.encoders(plant.q, plant.qd)[0])
    obs.update_imu(t, sensors.accelerometer(plant.q, plant.qd, plant.motor_torque(), plant.wrench_tree_forces()))
    touched = touched if touched is not None or wall.depth(np.r_[mech.end_effector(plant.q), 0.0]) <= 0 else t
    ref = ref + (0.0 if stopped else np.array([0.3, -0.3]) * 1e-3)  # the move: the tool goes down
    tau = 40.0 * (ref - motors) - 1.0 * plant.qd[mech.active]
    obs.command(t, tau)
    event = detector.update(obs.estimate_flat())
    if event is not None and event.kind == "contact" and stopped is None:
        stopped, ref = t, motors.copy()  # stop: hold where the contact was felt
        print(f"contact detected at {t * 1e3:.0f} ms, estimated force {np.round(event.wrench, 2)} N")
    plant.step(tau)
print(f"touched the wall at {touched * 1e3:.0f} ms: detected {(stopped - touched) * 1e3:.0f} ms later; held, the "
      f"tool is {-wall.depth(np.r_[mech.end_effector(plant.q), 0.0]) * 1e3:.2f} mm off the wall at {plant.t:.2f} s")
