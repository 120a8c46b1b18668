"""A feedforward goal's reference computed in a child process, beside the node's command stream.

The inverse dynamics of a long goal take seconds to a minute of Python and of library calls
that hold the GIL for up to a second (scipy's least-squares spline of the elastic inverse):
in a thread of the node they would still stall its timer. So each goal is computed in a
child process (multiprocessing's ``forkserver``: a clean server process, started once, forks
a child per goal with this module and the dynamics already imported), and a thread of the
node only waits for the answer, the reference pickled back. Cancelling (a newer goal, the
node asked to stop) kills the child at once. No ROS here: the child never imports rclpy.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import signal
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from elastic_pm_dyn.errors import ElasticPmDynError
from elastic_pm_dyn.model.description import Model
from elastic_pm_dyn.motion.feedforward import rigid_feedforward
from elastic_pm_dyn.motion.references import ElasticLineReference, JointReference
from elastic_pm_dyn.ros.feedforward.cartesian_goals import goal_reference
from elastic_pm_dyn.sim.held_feedforward import DEFAULT_INVERSE, HeldLineReference

CONTEXT = "forkserver"
POLL = 0.05  # [s] how often the waiting thread looks at its cancel flag
JOIN_WAIT = 1.0  # [s] for a killed child to be reaped
# Our errors (unreachable, singular), and numpy's should a solver inside it fail outright;
# ValueError: scipy on a degenerate input.
SOLVE_ERRORS = (ElasticPmDynError, np.linalg.LinAlgError, ValueError)


def prestart() -> None:
    """Start the fork server now, in the background (its imports take seconds; the first goal
    would wait for them)."""
    multiprocessing.set_forkserver_preload([__name__])
    multiprocessing.get_context(CONTEXT)  # (the server itself starts with the first child)
    from multiprocessing import forkserver
    forkserver.ensure_running()


def cartesian_reference(model: Model, path: Any, method: str, rate: float, shaper: str,
                        joint_names: Sequence[str], inverse: str = DEFAULT_INVERSE) -> Any:
    return goal_reference(model, path, method, rate, shaper, joint_names, inverse)


def elastic_line_reference(model: Model, line: Any, rate: float, joint_names: Sequence[str],
                           inverse: str = DEFAULT_INVERSE) -> ElasticLineReference:
    """The elastic line's reference: the held inverse's samples (``inverse`` held) or the
    continuous inverse's period means (continuous)."""
    if inverse == "held":
        return HeldLineReference(model, line, rate, list(joint_names))
    return ElasticLineReference(model, line, rate, list(joint_names))


def joint_reference(model: Model, joint_names: Sequence[str], times: Sequence[float],
                    positions: Sequence[Sequence[float]], velocities: Sequence[Sequence[float]] | None,
                    accelerations: Sequence[Sequence[float]] | None) -> JointReference:
    return JointReference(rigid_feedforward(model), joint_names, times, positions, velocities, accelerations)


def _child(conn: Any, compute: Callable[[], Any]) -> None:
    """The child process: compute, send ("ok", reference) or ("error", one line)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a terminal's Ctrl-C is for the node; it ends this child
    try:
        result = ("ok", compute())
    except SOLVE_ERRORS as err:
        result = ("error", str(err))
    except Exception as err:  # never lose a goal silently: its refusal says why
        result = ("error", f"{type(err).__name__}: {err}")
    with contextlib.suppress(OSError, ValueError):  # the node is gone
        conn.send(result)
    conn.close()


class GoalJob:
    """One goal: its reference computed in a child process, waited for by a daemon thread.
    ``done`` is set once it ends: ``reference`` (the answer), ``error`` (why there is none) or
    ``cancelled`` (a newer goal, or ``asked_to_stop()``: the child is killed)."""

    def __init__(self, what: str, start_ns: int | None, compute: Callable[[], Any],
                 asked_to_stop: Callable[[], bool] = lambda: False):
        self.what = what
        self.start_ns = start_ns  # the start on the node's clock; None: when ready
        self.received = time.monotonic()
        self.reference: Any = None
        self.error = ""
        self.cancelled = False
        self.cancel = threading.Event()
        self.done = threading.Event()
        self._compute = compute
        self._asked_to_stop = asked_to_stop
        self.thread = threading.Thread(target=self._run, name="feedforward-goal", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _stop_asked(self) -> bool:
        return self.cancel.is_set() or self._asked_to_stop()

    def _run(self) -> None:
        ctx = multiprocessing.get_context(CONTEXT)
        proc = None
        recv = send = None
        try:
            recv, send = ctx.Pipe(duplex=False)
            proc = ctx.Process(target=_child, args=(send, self._compute), name="feedforward-goal", daemon=True)
            proc.start()
            send.close()
            while True:
                if self._stop_asked():
                    self.cancelled = True
                    return
                if recv.poll(POLL):
                    try:
                        status, value = recv.recv()
                    except EOFError:  # it died without an answer (killed, out of memory)
                        proc.join(JOIN_WAIT)
                        self.error = f"its computation ended without an answer (exit code {proc.exitcode})"
                        return
                    if status == "ok":
                        self.reference = value
                    else:
                        self.error = value
                    return
        except Exception as err:  # the child could not start (fork server gone, no memory)
            self.error = f"its computation could not run: {type(err).__name__}: {err}"
        finally:
            if proc is not None and proc.is_alive():
                proc.kill()
            if proc is not None and proc.pid is not None:
                proc.join(JOIN_WAIT)
            for conn in (recv, send):
                if conn is not None:
                    conn.close()
            self.done.set()

    def stop(self, wait: float) -> None:
        """Cancel it and wait up to ``wait`` seconds for its thread (the child is killed)."""
        self.cancel.set()
        self.thread.join(wait)
