"""Desired motions and their rigid inverse dynamics (no simulation, no ROS).

``trajectory``: the motions themselves, time -> position, velocity, acceleration: the
quintic straight line of the end effector and smooth joint motions through waypoints.
``feedforward``: the rigid model's torques of a line, as a table at a control rate.
``references``: the same feedforward sampled one control instant at a time (what the
feedforward node publishes). ``manoeuvre``: the reference manoeuvre of the seed paper,
written once, from which the offline demo, the paper figures, the observer's test
recordings and the feedforward node's defaults are made.
"""
