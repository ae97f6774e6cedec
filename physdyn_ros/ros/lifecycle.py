# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""Managed (lifecycle) nodes: the states, transitions and refusals the suite's nodes share.

The standard ROS 2 state machine (rclpy.lifecycle.LifecycleNode, the services <node>/change_state,
<node>/get_state, ... that `ros2 lifecycle` and nav2's lifecycle_manager drive):

    unconfigured --configure--> inactive --activate--> active --deactivate--> inactive --cleanup--> unconfigured

- __init__ declares the parameters only (so `ros2 param` works in every state) and, with the parameter
  `autostart` (default true), configures and activates the node at once: the executables, `physdyn up` and the
  demo get an active node as before. With autostart false the node waits, unconfigured, for a manager.
- configure(): reads the parameters, loads what is heavy (the model, the simulator), creates the lifecycle
  publishers, services and timers. A bad value raises with the reason: the transition FAILS, the reason is
  logged (and shown on /diagnostics), whatever was made is released and the node stays unconfigured and alive.
- activate(): subscriptions are created and the lifecycle publishers enabled; services answer.
- deactivate(): subscriptions destroyed, publishers disabled; a service call answers success=false with
  "node is inactive (lifecycle state 'inactive')".
- cleanup(): everything configure() made is destroyed and the model released; the services are gone.
- shutdown (from any state) and errors release everything too. destroy_node() destroys the entities (rclpy)
  but leaves the node's attributes (model id, counters) readable; a node holding an outside resource (the
  simulator, the tf listener's thread) releases it in its own destroy_node.

Subclasses implement the four hooks and create their entities through configured_publisher / configured_service
/ configured_timer / configured_action_server (destroyed on cleanup) and active_subscription (destroyed on
deactivate), and call self.start() at the end of __init__.
"""
from __future__ import annotations

import functools
from typing import Any, Callable

from lifecycle_msgs.msg import State
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn

from .params import declare

SUCCESS, FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
RCLError = _rclpy.RCLError
ACTIVE, INACTIVE, UNCONFIGURED = (State.PRIMARY_STATE_ACTIVE, State.PRIMARY_STATE_INACTIVE,
                                  State.PRIMARY_STATE_UNCONFIGURED)


def lifecycle_state(node: Any) -> str | None:
    """The label of a lifecycle node's current state ('active', 'inactive', ...); None for a plain node."""
    machine = getattr(node, "_state_machine", None)
    return None if machine is None else str(machine.current_state[1])


class ManagedNode(LifecycleNode):
    """A LifecycleNode with the suite's conventions (see the module docstring)."""

    def __init__(self, node_name: str, **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.autostart: bool = declare(
            self, "autostart", True, "configure and activate the node at start (true: standalone, `physdyn up`); "
            "false: wait unconfigured for a lifecycle manager (ros2 lifecycle set <node> configure / activate)",
            read_only=True)
        #: Why the last transition failed ("" after a successful one); on /diagnostics.
        self.transition_error = ""
        #: Requests refused because the node was not active.
        self.refused_inactive = 0
        #: Callbacks that raised unexpectedly (logged with the traceback, the node went on).
        self.callback_errors = 0
        self._failure: BaseException | None = None
        self._configured: list[tuple[str, Any]] = []  # (kind, entity) made by configure(), destroyed on cleanup
        self._subscriptions_active: list[Any] = []  # made by activate(), destroyed on deactivate
        self._made = False  # configure() ran (cleanup() releases)
        service = getattr(self, "_service_change_state", None)
        if service is not None:  # rclpy raises (and never answers) on a transition the state does not have
            service.callback = self._answer_invalid_transitions(service.callback)

    def _answer_invalid_transitions(self, change_state: Callable) -> Callable:
        """rclcpp answers success=false to a transition that is not possible from the current state (configure
        when active, activate when unconfigured); Jazzy's rclpy raises RCLError in the service callback, so the
        caller never gets an answer. Answer as rclcpp does, with a warning."""
        def handler(req, resp):
            try:
                return change_state(req, resp)
            except RCLError as exc:
                what = req.transition.label or f"id {req.transition.id}"
                self.get_logger().warning(f"transition {what} is not possible from lifecycle state "
                                          f"'{self.state}': refused ({str(exc).split(',')[0]})")
                resp.success = False
                return resp
        return handler

    # ------------------------------------------------------------------------------------- subclass hooks
    def configure(self) -> None:
        """Read the parameters, load the model, create publishers / services / timers; raise on bad values."""

    def activate(self) -> None:
        """Create subscriptions, start work."""

    def deactivate(self) -> None:
        """Stop work (subscriptions are destroyed by the base class)."""

    def cleanup(self) -> None:
        """Release the model and whatever configure() loaded (entities are destroyed by the base class).
        Must cope with a configure() that failed half-way."""

    def describe(self) -> str:
        """One line for the 'active: ...' log message."""
        return ""

    # ----------------------------------------------------------------------------------------------- state
    @property
    def state(self) -> str:
        return lifecycle_state(self) or "unknown"

    @property
    def is_active(self) -> bool:
        return self._state_machine.current_state[0] == ACTIVE

    def not_serving(self) -> str:
        """The reason a request is refused outside the active state."""
        return (f"node is inactive (lifecycle state '{self.state}'): activate it, e.g. "
                f"`ros2 lifecycle set {self.get_fully_qualified_name()} activate`")

    def start(self) -> None:
        """Called at the end of a subclass's __init__: with autostart, configure and activate now. A node that
        cannot configure then raises the reason (the executable exits 1 with it, as before lifecycle)."""
        if not self.autostart:
            self.get_logger().info("unconfigured (autostart false): waiting for configure and activate")
            return
        try:
            for trigger, what in ((self.trigger_configure, "configure"), (self.trigger_activate, "activate")):
                if trigger() != SUCCESS:
                    failure, self._failure = self._failure, None
                    if failure is not None:
                        raise failure
                    raise RuntimeError(f"{what} failed: {self.transition_error or 'see the log'}")
        except BaseException:
            # The caller never gets this node to destroy: do it now, so that it leaves the ROS graph at once
            # (an undestroyed node stayed listed by other processes until its participant's lease ran out).
            self.destroy_node()
            raise

    # -------------------------------------------------------------------------------------------- entities
    def configured_publisher(self, msg_type, topic: str, qos) -> Any:
        """A lifecycle publisher (publishes only while active), destroyed on cleanup."""
        pub = self.create_lifecycle_publisher(msg_type, topic, qos)
        self._configured.append(("publisher", pub))
        return pub

    def configured_service(self, srv_type, name: str, callback: Callable, **kwargs) -> Any:
        """A service that exists from configure to cleanup and answers only while active; otherwise its response
        has success=false and the reason (every service of the suite has success and message)."""
        @functools.wraps(callback)
        def guarded(req, res):
            if not self.is_active:
                self.refused_inactive += 1
                res.success, res.message = False, self.not_serving()
                return res
            try:
                return callback(req, res)
            except Exception as exc:  # noqa: BLE001 - a bug answers this request with its reason, the node lives
                self.callback_failure(f"service {name}", exc)
                res.success, res.message = False, f"internal error: {type(exc).__name__}: {exc}"
                return res

        srv = self.create_service(srv_type, name, guarded, **kwargs)
        self._configured.append(("service", srv))
        return srv

    def configured_timer(self, period: float, callback: Callable, **kwargs) -> Any:
        """A timer from configure to cleanup; its callback runs only while the node is active."""
        @functools.wraps(callback)
        def guarded():
            if self.is_active:
                try:
                    callback()
                except Exception as exc:  # noqa: BLE001 - one failed tick must not stop the timer or the node
                    self.callback_failure("timer", exc)

        timer = self.create_timer(period, guarded, **kwargs)
        self._configured.append(("timer", timer))
        return timer

    def configured_action_server(self, action_type, name: str, execute_callback: Callable,
                                 goal_callback: Callable | None = None, **kwargs) -> Any:
        """An rclpy ActionServer from configure to cleanup that accepts goals only while active (a goal otherwise
        is rejected, with the reason logged: the action protocol carries none). A running goal is not stopped by
        deactivate: its execute callback should check `is_active` between steps and abort with not_serving()."""
        from rclpy.action import ActionServer, GoalResponse

        def accept(goal_request):
            if not self.is_active:
                self.refused_inactive += 1
                self.get_logger().warning(f"{name}: goal rejected: {self.not_serving()}")
                return GoalResponse.REJECT
            return goal_callback(goal_request) if goal_callback is not None else GoalResponse.ACCEPT

        server = ActionServer(self, action_type, name, execute_callback, goal_callback=accept, **kwargs)
        self._configured.append(("action_server", server))
        return server

    def active_subscription(self, msg_type, topic: str, callback: Callable, qos, **kwargs) -> Any:
        """A subscription from activate to deactivate (latched topics are delivered again on activation)."""
        @functools.wraps(callback)
        def guarded(msg):
            try:
                callback(msg)
            except Exception as exc:  # noqa: BLE001 - one bad message is dropped with its reason, the node lives
                self.callback_failure(f"subscription {topic}", exc)

        sub = self.create_subscription(msg_type, topic, guarded, qos, **kwargs)
        self._subscriptions_active.append(sub)
        return sub

    def callback_failure(self, where: str, exc: BaseException) -> None:
        """Log a callback's unexpected exception with its traceback; counted on /diagnostics (callback_errors)."""
        import traceback

        self.callback_errors += 1
        self.get_logger().error(f"{where} failed: {type(exc).__name__}: {exc}\n"
                                + "".join(traceback.format_exception(exc)).rstrip())

    def _destroy_subscriptions(self) -> None:
        subs, self._subscriptions_active = self._subscriptions_active, []
        for sub in subs:
            self.destroy_subscription(sub)

    def _release(self) -> None:
        """cleanup() and the destruction of every configured entity (newest first); safe to call twice."""
        self._destroy_subscriptions()
        if self._made:
            self._made = False
            try:
                self.cleanup()
            except Exception as exc:  # noqa: BLE001 - release the rest anyway
                self.get_logger().error(f"cleanup: {type(exc).__name__}: {exc}")
        made, self._configured = self._configured, []
        for kind, entity in reversed(made):
            if kind == "publisher":
                self.destroy_lifecycle_publisher(entity)
            elif kind == "service":
                self.destroy_service(entity)
            elif kind == "action_server":
                entity.destroy()
            else:
                self.destroy_timer(entity)

    def _transition_failed(self, what: str, exc: BaseException, back_to: str) -> TransitionCallbackReturn:
        self._failure = exc
        self.transition_error = f"{what} failed: {exc}"
        self.get_logger().error(f"{self.transition_error} (the node stays {back_to})")
        return FAILURE

    # ------------------------------------------------------------------------------ rclpy transition callbacks
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._failure = None
        self._made = True
        try:
            self.configure()
        except Exception as exc:  # noqa: BLE001 - a bad value: FAILURE, stay unconfigured, keep running
            self._release()
            return self._transition_failed("configure", exc, "unconfigured")
        self.transition_error = ""
        self.get_logger().info("configured (inactive)")
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._failure = None
        ret = super().on_activate(state)  # enables the lifecycle publishers (activate() may publish)
        if ret != SUCCESS:
            return ret
        try:
            self.activate()
        except Exception as exc:  # noqa: BLE001
            super().on_deactivate(state)
            self._destroy_subscriptions()
            return self._transition_failed("activate", exc, "inactive")
        self.transition_error = ""
        self.get_logger().info(f"active: {self.describe()}".rstrip(": "))
        return ret

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        ret = super().on_deactivate(state)
        self._destroy_subscriptions()
        try:
            self.deactivate()
        except Exception as exc:  # noqa: BLE001 - the node is inactive anyway
            self.get_logger().error(f"deactivate: {type(exc).__name__}: {exc}")
        self.get_logger().info("deactivated (inactive): requests are refused until activate")
        return ret

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("cleaned up (unconfigured): model and resources released")
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if state.state_id == ACTIVE:
            super().on_deactivate(state)
            try:
                self.deactivate()
            except Exception as exc:  # noqa: BLE001
                self.get_logger().error(f"deactivate: {type(exc).__name__}: {exc}")
        self._release()
        return SUCCESS

    def destroy_node(self) -> None:
        super().destroy_node()
        # Jazzy's rclpy never destroys the lifecycle state machine, which holds the rcl node: the node stayed in
        # the ROS graph of every other process until this one exited (test_ros_launch's demo then refused to
        # start: "nodes ['sim', 'perception'] already run"). Destroying it lets the node go.
        self._state_machine.destroy_when_not_in_use()

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """An exception escaped a transition: release everything and return to unconfigured."""
        self.get_logger().error(f"error in a transition from '{state.label}': releasing everything")
        super().on_deactivate(state)
        self._release()
        return SUCCESS
