"""The plant node's simulator services (docs/ros.md): ``~/reset``, ``~/set_state``, ``~/pause``,
``~/unpause`` and ``~/step``. Each answers ``success: false`` with the reason for a request it
cannot serve, and never lets an error end the node."""

from __future__ import annotations

import time
from typing import Any

from elastic_pm_dyn_msgs.srv import SetJointState, StepPeriods
from std_srvs.srv import Trigger

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.ros.node_main import stopping

MAX_STEP_REQUEST = 1_000_000  # ~/step: periods in one request (the executor waits for them)


class PlantServices:
    """The services of a plant node (``node``: a :class:`~elastic_pm_dyn.ros.plant.node.PlantNode`)."""

    def __init__(self, node: Any):
        self.node = node
        node.create_service(Trigger, "~/reset", self.on_reset)
        node.create_service(SetJointState, "~/set_state", self.on_set_state)
        node.create_service(Trigger, "~/pause", self.on_pause)
        node.create_service(Trigger, "~/unpause", self.on_unpause)
        node.create_service(StepPeriods, "~/step", self.on_step)

    def on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        node = self.node
        try:
            node.plant.reset()
            node.restarted()
            response.success = True
            response.message = f"reset to the initial state at t = {node.plant.t:.6g} s"
            node.get_logger().info(response.message)
        except Exception as err:  # never die on a service call: answer why
            response.success = False
            response.message = f"reset failed: {type(err).__name__}: {err}"
            node.get_logger().error(response.message)
        return response

    def on_set_state(self, request: SetJointState.Request,
                     response: SetJointState.Response) -> SetJointState.Response:
        node, s = self.node, request.state
        try:
            response.message = node.plant.set_state(s.name, s.position, s.velocity)
            response.success = True
            node.restarted()
            node.get_logger().info(response.message)
        except InputError as err:
            response.success = False
            response.message = f"set_state rejected: {err}"
            node.get_logger().warning(response.message)
        except Exception as err:  # never die on a service call: answer why (the state is unchanged)
            response.success = False
            response.message = f"set_state failed: {type(err).__name__}: {err}"
            node.get_logger().error(response.message)
        return response

    def on_pause(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        node = self.node
        response.success = True
        if node.paused:
            response.message = f"already paused at t = {node.plant.t:.6g} s"
            return response
        node.paused = True
        node.stats.pause(time.monotonic())
        if node.step_timer is not None:
            node.step_timer.cancel()
        response.message = (f"paused at t = {node.plant.t:.6g} s ({node.plant.k} periods)"
                            + ("; commands queue until unpause or step" if node.sync.answers_every_command else ""))
        node.get_logger().info(response.message)
        return response

    def on_unpause(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        node = self.node
        response.success = True
        if not node.paused:
            response.message = f"not paused (t = {node.plant.t:.6g} s)"
            return response
        node.paused = False
        node.stats.resume(time.monotonic())
        node.resume()
        response.message = f"running from t = {node.plant.t:.6g} s"
        node.get_logger().info(response.message)
        return response

    def on_step(self, request: StepPeriods.Request, response: StepPeriods.Response) -> StepPeriods.Response:
        """N periods at once while paused, each with the torque the mode would hold (see StepPeriods.srv)."""
        node = self.node
        response.periods_advanced = 0
        n = request.periods
        if not node.paused:
            response.success, response.message = False, "not paused: call ~/pause first (steps are counted exactly)"
        elif node.plant.fault is not None:
            response.success = False
            response.message = f"integration stopped: {node.plant.fault}; call ~/reset or ~/set_state"
        elif n > MAX_STEP_REQUEST:
            response.success, response.message = False, f"{n} periods: at most {MAX_STEP_REQUEST} per request"
        else:
            try:
                for _ in range(n):
                    if stopping():  # Ctrl-C or SIGTERM: answer with what was done, then the node ends
                        break
                    if not node.step_period(*node.sync.step_torque()):
                        break
                    response.periods_advanced += 1
            except Exception as err:  # never die on a service call: answer why
                node.get_logger().error(f"step failed: {type(err).__name__}: {err}")
            response.success = response.periods_advanced == n
            why = "the node is stopping" if stopping() else node.plant.fault or "see the log"
            response.message = (f"advanced {response.periods_advanced} of {n} period(s) to t = {node.plant.t:.6g} s"
                                + ("" if response.success else f"; stopped: {why}"))
        response.sim_time = node.plant.t
        if response.success:  # one severity per call site (rclpy's rule)
            node.get_logger().info(f"step: {response.message}")
        else:
            node.get_logger().warning(f"step: {response.message}")
        return response
