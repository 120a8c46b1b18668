"""ament_python package: ``colcon build`` in a ROS 2 workspace, or ``pip install -e .``."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "elastic_pm_dyn"

setup(
    name=PACKAGE,
    version="0.1.0",
    description="Dynamics of elastic parallel manipulators: multipliers, Lagrange-D'Alembert, SCDD",
    license="Apache-2.0",
    python_requires=">=3.11",
    packages=find_packages(exclude=["test", "test.*", "bench", "bench.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=[
        "setuptools",
        "numpy>=1.26",
        "scipy>=1.11",
        "numba>=0.60",
        "pyyaml>=6",
        "matplotlib>=3.8",
        "rosbags>=0.11,<0.12",
    ],
    # pin: the Pinocchio cross-checks (and the benchmark); mujoco: reading MJCF models and
    # their cross-check (and the benchmark); drake: the peer reading of SDFormat files (the
    # reader itself needs nothing); hypothesis: the property-based fuzz suite;
    # batch: `elastic-pm-dyn batch --cluster` (Dask distributed) and the Parquet results table
    # (pyarrow); the tests run both.
    extras_require={"test": ["pytest>=8", "ruff", "pin", "mujoco", "drake", "hypothesis>=6.100",
                             "dask[distributed]>=2024.1", "pyarrow>=14"],
                    "bench": ["pin", "mujoco", "dask[distributed]>=2024.1", "pyarrow>=14"],
                    "mjcf": ["mujoco"], "batch": ["dask[distributed]>=2024.1", "pyarrow>=14"]},
    zip_safe=False,
    entry_points={
        "console_scripts": [
            # elastic_pm_dyn.entry: Ctrl-C from the first import on ends with one line, exit 130
            "elastic-pm-dyn = elastic_pm_dyn.entry:cli",
            "plant_node = elastic_pm_dyn.entry:plant_node",
            "observer_node = elastic_pm_dyn.entry:observer_node",
            "feedforward_node = elastic_pm_dyn.entry:feedforward_node",
            "recorder_node = elastic_pm_dyn.entry:recorder_node",
        ],
    },
)
