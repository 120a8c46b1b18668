"""Desired motions and their inverse dynamics (no simulation, no ROS).

``trajectory``: the motions themselves, time -> position, velocity, acceleration: straight
lines with a rest-to-rest law (``time_laws``: quintic to 9th order) and smooth joint
motions through waypoints; ``poses``: a platform's 6-D pose line (SO(3) geodesic);
``waypoints``: waypoint files as paths. ``task``: the coordinates a path prescribes and the
motion the closure gives them. ``elastic_inverse``: the elastic model's inverse dynamics
along a path; ``shaping``: ZV/ZVD/EI input shapers of a path. ``feedforward``: rigid,
elastic or shaped torque tables at a control rate. ``references``: the same sampled one
control instant at a time (what the feedforward node publishes). ``manoeuvre``: the
reference manoeuvre of the seed paper, written once, from which the offline demo, the
paper figures, the observer's test recordings and the feedforward node's defaults are made.
"""
