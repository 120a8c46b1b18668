"""Simulation: integrators, constraint stabilisation, torque sources, results."""
