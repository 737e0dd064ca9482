"""``odometry_lifecycle_node``: ``odometry_node`` as a managed (lifecycle) node.

For stacks brought up by a lifecycle manager (Nav2's nav2_lifecycle_manager), which
configures and activates nodes by name through lifecycle_msgs' ChangeState service.
Same parameters, topics, QoS, frames, /diagnostics, reset service and ~/set_pose as
``odometry_node``: both run :class:`diffdrive_odom.ros.odometry_node.OdometryEndpoints`
(or, with ``open_loop``, :class:`diffdrive_odom.ros.open_loop.OpenLoopEndpoints`).

unconfigured: parameters declared, nothing else. configure: parameters validated (a
bad one fails the transition with one line naming it), endpoints created; inactive:
readings integrated, nothing published; active: odometry, /tf and /diagnostics
published. Integrating while inactive keeps the pose continuous across deactivate /
activate (REP 105: odom never jumps). cleanup forgets the pose; shutdown from any state.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from lifecycle_msgs.srv import ChangeState
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from diffdrive_odom.ros.odometry_node import OdometryEndpoints, odometry_endpoints
from diffdrive_odom.ros.parameters import declare, parameter_values
from diffdrive_odom.ros.runtime import run
from diffdrive_odom.settings.errors import ParameterError
from diffdrive_odom.settings.odometry import ODOMETRY_PARAMS

if TYPE_CHECKING:
    from diffdrive_odom.ros.open_loop import OpenLoopEndpoints

NODE_NAME = "odometry_lifecycle_node"


class OdometryLifecycleNode(LifecycleNode):
    """Wheel odometry under a lifecycle manager: configure builds it, activate publishes."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        # Declared now, checked at configure: while unconfigured any value can be set,
        # so a bad one given at start can be fixed with set_parameters and configure retried.
        # One the declared type or range cannot hold keeps its default and is the reason
        # configure fails until a value is set.
        self._refused: dict[str, ParameterError] = {}
        declare(self, ODOMETRY_PARAMS, self._refused)
        self.add_post_set_parameters_callback(
            lambda params: [self._refused.pop(p.name, None) for p in params])
        self._odometry: OdometryEndpoints | OpenLoopEndpoints | None = None
        service = self._service_change_state
        self._change_state = service.callback
        service.callback = self._on_change_state

    def _on_change_state(
        self, request: ChangeState.Request, response: ChangeState.Response
    ) -> ChangeState.Response:
        """The ChangeState of rclpy, except that a transition invalid in this state is refused.

        rclpy 7.1 raises out of the service for an id the current state has no such
        transition for (a label it refuses), which ends the process: a manager's
        mistake must not kill the node (rcl_lifecycle already logs a warning).
        """
        try:
            result: ChangeState.Response = self._change_state(request, response)
        except _rclpy.RCLError:
            response.success = False
            return response
        return result

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Validate the parameters and create the endpoints; a bad value FAILS, one line."""
        try:
            for err in self._refused.values():
                raise err
            self._odometry = odometry_endpoints(
                self, parameter_values(self, ODOMETRY_PARAMS))
        except ParameterError as err:
            self.get_logger().error(f"configure failed: {err}")
            return TransitionCallbackReturn.FAILURE
        return super().on_configure(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Destroy the endpoints and forget the pose: back to unconfigured."""
        self._forget()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """From any state: destroy what configure built (nothing if unconfigured)."""
        self._forget()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """A transition raised: drop what was built, so the node is back to unconfigured."""
        self.get_logger().error(f"transition from {state.label} raised; back to unconfigured")
        self._forget()
        return super().on_error(state)

    def _forget(self) -> None:
        if self._odometry is not None:
            self._odometry.destroy()
            self._odometry = None


def main(args: list[str] | None = None) -> int:
    """Console script / ``ros2 run diffdrive_odom odometry_lifecycle_node``."""
    return run(OdometryLifecycleNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
