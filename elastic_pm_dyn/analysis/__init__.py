"""Run analysis without ROS (rclpy is never imported): bags and arrays in, numbers and PNG plots out.

``metrics`` holds path deviation, residual-vibration fitting, spectra, aliasing
checks and message-stream timing statistics; ``plots`` turns recorded runs into
the figures of the seed paper (path, branch forces, closure gap) and a few more
(motor torques, tracking error, spectrum).

Bags: ``bags`` finds the analysed topics of a rosbag2 (read through :mod:`elastic_pm_dyn.bags`)
by role and type and streams them with bounded memory (``streams``); ``run_data`` turns topics into model
quantities (forward kinematics, closure gap, hold phase); ``report`` makes the metrics of one run
or several side by side as typed parts of the report (``report_types``: the report as objects, what
``analyze`` returns; its ``to_dict()`` is ``summary.json``), ``summary.md`` and the plots;
``export`` writes one CSV per topic; ``paper`` reproduces the paper's Figs. 2-4; ``cli``
adds ``analyze``, ``export`` and ``paper-figures`` to ``elastic-pm-dyn``.
"""
