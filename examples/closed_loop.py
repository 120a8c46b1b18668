"""Close the loop through ROS 2: plant with sensors, state observer, PD + feedforward controller.

Starts four node processes on a private, loopback-only ROS domain, all in lockstep:
- ``plant_node`` simulating the elastic machine with motor encoders, an end-effector
  accelerometer and an unknown motor torque (flat 2-200 Hz, 0.02 N m RMS);
- ``observer_node`` estimating every joint and the branch forces from the commands and
  sensors, publishing on ``observer/joint_states`` and ``observer/branch_forces``;
- ``feedforward_node`` as the controller: rigid feedforward of the reference line plus a PD on
  the encoders (``feedback.kp/kd``), answering each estimate with the command of its stamp;
- ``recorder_node`` writing every topic into a bag.
Then it reads the bag back and prints how well the observer estimated the branch forces,
against the open loop (the model under the same commands, without the unknown torque).

Run (needs ROS 2 Jazzy's rclpy and the elastic_pm_dyn_msgs package):

    python examples/closed_loop.py [--model config/five_bar.yaml] [--duration 0.5] [--seed 1]
        [--observer-config tuned.yaml] [--out DIR] [--domain-id ID]

DIR (default closed_loop_out) receives the bag, summary.json, branch_forces.png (estimate
with its 2-sigma band, truth, open loop), path.png, torques.png and the node logs. The same
as ``elastic-pm-dyn ros-demo --observer``; the nodes' wiring is docs/nodes.md, "Closing the loop".
"""

from __future__ import annotations

import argparse
from pathlib import Path

from elastic_pm_dyn.ros.loop_demo import LoopOptions, run_loop_demo

CONFIG = Path(__file__).resolve().parents[1] / "config"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", default=str(CONFIG / "five_bar.yaml"))
    p.add_argument("--elastic-dof-per-chain", type=int, default=None)
    p.add_argument("--duration", type=float, default=0.5, help="[s] of loop")
    p.add_argument("--seed", type=int, default=1, help="sensor noise and disturbance")
    p.add_argument("--observer-config", default=None, help="e.g. a file written by elastic-pm-dyn tune")
    p.add_argument("--out", default="closed_loop_out")
    p.add_argument("--domain-id", type=int, default=None)
    args = p.parse_args()

    options = LoopOptions(
        model=Path(args.model),
        elastic_dof_per_chain=args.elastic_dof_per_chain,
        seed=args.seed,
        duration=args.duration,
        observer_config=Path(args.observer_config) if args.observer_config else None,
        domain_id=args.domain_id,
    )
    s = run_loop_demo(Path(args.out), options)

    print(f"{s['loop_periods']} periods of 1 ms in lockstep, one estimate per plant state: "
          f"{s['plant_states_without_estimate'] == 0}")
    print(f"branch-force error RMS: observer {s['branch_force_error_rms_N']:.4g} N, "
          f"open loop {s['branch_force_error_rms_open_loop_N']:.4g} N "
          f"(ratio {s['branch_force_error_ratio_to_open_loop']:.3f})")
    print(f"NEES of the mechanical states in its 95 % band: {100 * s['nees_in_band']:.1f} % of the samples")
    print(f"live estimates equal offline observe over the bag: {s['live_equals_offline']}")
    pd = s["controller"]
    print(f"commands that are the PD law on the encoder sample of their stamp: "
          f"{pd['commands_equal_to_pd_on_their_sample']} of {pd['commands_checked']}")


if __name__ == "__main__":
    main()
