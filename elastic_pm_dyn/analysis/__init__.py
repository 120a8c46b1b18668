"""Run analysis without ROS: arrays in, numbers and PNG plots out.

``metrics`` holds path deviation, residual-vibration fitting, spectra, aliasing
checks and message-stream timing statistics; ``plots`` turns recorded runs into
the figures of the seed paper (path, branch forces, closure gap) and a few more
(motor torques, tracking error, spectrum). Reading bags belongs elsewhere.
"""
