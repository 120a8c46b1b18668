"""Simulation: integrators, constraint stabilisation, torque sources, results, and the per-period
plant stepper (:mod:`.plant`) behind the plant node."""
