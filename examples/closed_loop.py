"""Close the loop through ROS 2: plant with sensors, state observer, PD + feedforward controller.

Starts, in lockstep on a loopback-only ROS domain (``ROS_DOMAIN_ID`` when set, else a private
one): ``plant_node`` (the elastic machine with encoders, an accelerometer and an unknown 2-200 Hz
motor torque), ``observer_node`` (joints
and branch forces), ``feedforward_node`` as the controller (rigid feedforward plus a PD on the
encoders) and ``recorder_node``; then reads the bag back and prints how well the observer
estimated the branch forces against the open loop. Needs rclpy and elastic_pm_dyn_msgs.
Run: ``python examples/closed_loop.py`` (the same as ``elastic-pm-dyn ros-demo --observer``;
the wiring: docs/nodes.md, "Closing the loop"). Writes the bag, plots and logs to closed_loop_out.
"""

from pathlib import Path

from elastic_pm_dyn.ros.demos.loop_demo import LoopOptions, run_loop_demo

MODEL = Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"
DURATION, SEED = 0.5, 1  # [s] of loop; seed of the sensor noise and the disturbance
OBSERVER_CONFIG = None  # e.g. a file written by elastic-pm-dyn tune

s = run_loop_demo(Path("closed_loop_out"), LoopOptions(model=MODEL, seed=SEED, duration=DURATION,
                                                       observer_config=OBSERVER_CONFIG))
print(f"{s['loop_periods']} periods of 1 ms in lockstep, one estimate per plant state: "
      f"{s['plant_states_without_estimate'] == 0}")
print(f"branch-force error RMS: observer {s['branch_force_error_rms_N']:.4g} N, open loop "
      f"{s['branch_force_error_rms_open_loop_N']:.4g} N (ratio {s['branch_force_error_ratio_to_open_loop']:.3f})")
print(f"NEES of the mechanical states in its 95 % band: {100 * s['nees_in_band']:.1f} % of the samples")
print(f"live estimates equal offline observe over the bag: {s['live_equals_offline']}")
pd = s["controller"]
print(f"commands that are the PD law on the encoder sample of their stamp: "
      f"{pd['commands_equal_to_pd_on_their_sample']} of {pd['commands_checked']}")
