"""The console scripts' entry points: Ctrl-C at any moment ends the program with one line
and status 130 (128 + SIGINT, as a shell reports it), never a traceback.

Each script imports only this module (and the package's small ``__init__``); the module
with the program's ``main`` (numpy, numba, rclpy, the model) is imported inside the guard,
so an interrupt during those imports, a node's start-up or numba's first compile is
caught like one during the run. Within a run, ``elastic-pm-dyn`` keeps its own handling
(``simulate`` writes the rows done so far) and a spinning node stops cleanly on SIGINT.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys

from elastic_pm_dyn import interrupts

EXIT_INTERRUPTED = 130

# From here every SIGINT counts (one that a finalizer swallows during the imports too); until
# run()'s guard is up it is only counted, then raised there.
interrupts.install()


def run(program: str, target: str, argv: list[str] | None = None) -> int:
    """Import ``target`` ('module:function') and call it with ``argv``; on Ctrl-C one line, and the
    process ends with status 130."""
    try:
        interrupts.arm()
        module, func = target.split(":")
        return importlib.import_module(module).__dict__[func](argv)
    except KeyboardInterrupt:
        interrupts.ending()  # no finalizer's traceback after our one line
        with contextlib.suppress(KeyboardInterrupt):  # a second Ctrl-C while saying so
            print(f"{program}: interrupted (Ctrl-C)", file=sys.stderr)
            sys.stdout.flush()
            sys.stderr.flush()
        # End here, without the interpreter's finalization: an import the interrupt cut short
        # leaves native objects (llvmlite's, numba's) half-built, and finalizing them can crash
        # in C ("free(): double free detected", status -6 instead of 130; seen on a loaded
        # machine). Nothing waits for it: main's own finally blocks (files, nodes) have run.
        os._exit(EXIT_INTERRUPTED)


def cli(argv: list[str] | None = None) -> int:
    return run("elastic-pm-dyn", "elastic_pm_dyn.cli:main", argv)


def plant_node(argv: list[str] | None = None) -> int:
    return run("plant_node", "elastic_pm_dyn.ros.plant.node:main", argv)


def observer_node(argv: list[str] | None = None) -> int:
    return run("observer_node", "elastic_pm_dyn.ros.observer.node:main", argv)


def feedforward_node(argv: list[str] | None = None) -> int:
    return run("feedforward_node", "elastic_pm_dyn.ros.feedforward.node:main", argv)


def recorder_node(argv: list[str] | None = None) -> int:
    return run("recorder_node", "elastic_pm_dyn.ros.recorder.node:main", argv)


PROGRAMS = {"elastic-pm-dyn": cli, "plant_node": plant_node, "observer_node": observer_node,
            "feedforward_node": feedforward_node, "recorder_node": recorder_node}


def _exit(status: int) -> None:
    try:
        sys.exit(status)
    except KeyboardInterrupt:  # pragma: no cover - a Ctrl-C in the last instructions
        sys.exit(EXIT_INTERRUPTED)


if __name__ == "__main__":  # python -m elastic_pm_dyn.entry PROGRAM ARGS...
    if len(sys.argv) < 2 or sys.argv[1] not in PROGRAMS:
        print(f"usage: python -m elastic_pm_dyn.entry {{{','.join(PROGRAMS)}}} [ARGS...]", file=sys.stderr)
        _exit(2)
    sys.argv = sys.argv[1:]  # as the console script would see it: argparse and rclpy read sys.argv
    _exit(PROGRAMS[sys.argv[0]](None))
