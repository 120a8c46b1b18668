"""A straight-line manoeuvre on the elastic five-bar: rigid feedforward in, elastic motion out.

The rigid model's torques for a quintic line (sampled at the control rate, held) drive the
elastic machine; they do not know the springs, so the path leaves the line by micrometres and
the rods ring at the stop. Run: ``python examples/simulate_manoeuvre.py`` (writes manoeuvre.csv).
"""

from pathlib import Path

import numpy as np

import elastic_pm_dyn as epd

MODEL = Path(__file__).resolve().parents[1] / "config" / "five_bar.yaml"
MOVE, HOLD = 0.2, 0.1  # [s] the move, then the time held at its end

model = epd.load_model(MODEL)
ref = epd.REFERENCE_MANOEUVRE  # the seed paper's line; only its timing is changed here
line = epd.QuinticLine(np.array(ref.start), np.array(ref.end), move=MOVE, hold=HOLD)
times, torques, motors = epd.line_torques(model, line, ref.control_rate)
run = epd.simulate(model, epd.TorqueTable(times, torques), line.duration, "manoeuvre.csv", sample=ref.sample)

u = (line.end - line.start) / np.linalg.norm(line.end - line.start)
rel = run.ee - line.start
off_line = np.linalg.norm(rel - np.outer(rel @ u, u), axis=1)  # perpendicular distance from the line
print(f"motors {', '.join(motors)}: {len(times)} torque samples at {ref.control_rate:g} Hz")
print(f"largest distance from the straight line: {off_line.max() * 1e6:.3f} um")
print(f"final position error: {np.linalg.norm(run.ee[-1] - line.end) * 1e6:.3f} um")
for i, branch in enumerate(model.branches):
    print(f"peak force in branch {branch.name}: {np.abs(run.branch_forces[:, i]).max():.2f} N")
