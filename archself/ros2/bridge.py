"""The MAPE-K loop as a ROS 2 node: topics in, lifecycle and parameter services out.

:class:`Ros2Bridge` holds a :class:`~archself.live.LiveLoop` (the same loop as
``archself live``: Δ and stability from the compiled models, no rollout) and a
:mod:`rclpy` node that

* subscribes to every module output, residual signal and health topic
  (:mod:`archself.ros2.topics`) and keeps the latest value of each;
* runs a cycle every ``runtime.period_s``: on its own timer (``clock="timer"``,
  the node's clock, ROS time if ``use_sim_time``), or in lock step with a plant
  that publishes a tick after each measurement and waits for the answer
  (``clock="tick"``, what the demo plant and the tests do);
* turns a configuration command into lifecycle transitions
  (``/<node>/change_state``, ``lifecycle_msgs/srv/ChangeState``) of the nodes that
  are lifecycle nodes, and a parameter command into ``/<node>/set_parameters``
  (``rcl_interfaces/srv/SetParameters``);
* reports to the loop the configuration the nodes' lifecycle states show (a
  refused transition is seen at the next cycle, as in ``archself live``);
* publishes each cycle's decision record on ``/archself/decisions`` and every
  command with its system_modes names (``archself export --to ros2-modes``) on
  ``/archself/mode``.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.io.jsondata import DecisionRecordDoc, document, jsonable
from archself.live import Command, LiveLoop
from archself.model.architecture import Architecture
from archself.reports.export import node_modules
from archself.ros2.base import Ros2Error, require_rclpy
from archself.ros2.topics import (
    ACK,
    DECISIONS,
    MODE,
    TICK,
    configuration_of,
    health_topic,
    measured_signals,
    output_topic,
    parameter_value,
    residual_topic,
    transitions,
)

__all__ = ["Ros2Bridge", "array_msg", "array_value", "run_bridge"]

_TRANSITION_IDS = {"configure": 1, "activate": 3, "deactivate": 4}  # lifecycle_msgs/Transition
_GOAL = {"configure": "inactive", "activate": "active", "deactivate": "inactive"}


def array_msg(value: Any) -> Any:
    """A number or an array as ``std_msgs/Float64MultiArray`` (one layout dim per axis)."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    a = np.asarray(value, dtype=float)
    msg = Float64MultiArray()
    stride = int(a.size)
    for i, n in enumerate(a.shape):
        msg.layout.dim.append(MultiArrayDimension(label=f"d{i}", size=int(n), stride=stride))
        stride = stride // max(int(n), 1)
    msg.data = a.ravel().tolist()
    return msg


def array_value(msg: Any) -> Any:
    """The inverse of :func:`array_msg`: a float or an array of the layout's shape."""
    data = np.asarray(msg.data, dtype=float)
    if not msg.layout.dim:
        return float(data[0]) if data.size else math.nan
    return data.reshape([int(d.size) for d in msg.layout.dim])


class Ros2Bridge:
    """The MAPE-K loop of ``arch`` as a ROS 2 node.

    Parameters
    ----------
    arch : Architecture
        The architecture the robot runs (validated).
    nodes : list of str, optional
        The modules that are ROS 2 nodes (default: the functional ones,
        :func:`archself.reports.export.node_modules`). Those that offer the
        lifecycle services are driven through them.
    clock : {"timer", "tick"}
        What starts a cycle (module docstring).
    configuration, rollout
        As :class:`~archself.live.LiveLoop`.
    node_name : str
        The bridge's ROS 2 node name.
    service_timeout_s : float
        How long to wait for a node's services at start and for each answer.
    use_sim_time : bool
        The node's clock is ``/clock`` (ROS simulated time), for ``clock="timer"``.

    Attributes
    ----------
    loop : LiveLoop
    node : rclpy.node.Node
    states : dict
        Lifecycle node → its state label as last known.
    stats : dict
        Counters and timings (:meth:`summary`).
    """

    def __init__(
        self,
        arch: Architecture,
        *,
        nodes: Sequence[str] | None = None,
        clock: str = "timer",
        configuration: str | None = None,
        rollout: str = "refuse",
        node_name: str = "archself",
        service_timeout_s: float = 10.0,
        use_sim_time: bool = False,
    ) -> None:
        if clock not in ("timer", "tick"):
            raise Ros2Error(f"clock must be 'timer' or 'tick', not {clock!r}")
        rclpy = require_rclpy()
        from lifecycle_msgs.msg import TransitionEvent
        from lifecycle_msgs.srv import ChangeState, GetState
        from rcl_interfaces.srv import SetParameters
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64, Float64MultiArray, String

        self.arch = arch
        self.nodes = node_modules(arch, list(nodes) if nodes is not None else None)
        self.clock = clock
        self.timeout_s = float(service_timeout_s)
        if not rclpy.ok():
            rclpy.init()
        self.node = rclpy.create_node(node_name)
        if use_sim_time:
            from rclpy.parameter import Parameter

            self.node.set_parameters([Parameter("use_sim_time", value=True)])
        self.loop = LiveLoop(arch, configuration=configuration, rollout=rollout,
                             start_s=0.0 if clock == "tick" else self._now())
        self.outputs: dict[str, dict[str, Any]] = {}
        self.signals: dict[str, dict[str, float]] = {}
        self.health: dict[str, str | None] = {}
        self.states: dict[str, str] = {}
        self.lifecycle: list[str] = []
        self.received = 0
        self.ended: dict[str, Any] | None = None
        self._tick: dict[str, Any] | None = None
        self._pending = 0
        self._ack: dict[str, Any] | None = None
        self._last_heard = time.monotonic()
        self.stats: dict[str, Any] = {"cycle_ms": [], "act_ms": [], "ticks": 0,
                                      "refused": [], "skipped": 0}
        self._types = {"ChangeState": ChangeState, "GetState": GetState,
                       "SetParameters": SetParameters}
        depth = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        outputs, residuals = measured_signals(arch)
        for m, s in outputs:
            self.node.create_subscription(
                Float64MultiArray, output_topic(m, s),
                lambda msg, m=m, s=s: self._store(self.outputs, m, s, array_value(msg)), depth)
        for m, s in residuals:
            self.node.create_subscription(
                Float64, residual_topic(m, s),
                lambda msg, m=m, s=s: self._store(self.signals, m, s, float(msg.data)), depth)
        for m in arch.modules:
            self.node.create_subscription(String, health_topic(m),
                                          lambda msg, m=m: self._on_health(m, msg.data), depth)
        for n in self.nodes:
            self.node.create_subscription(
                TransitionEvent, f"/{n}/transition_event",
                lambda msg, n=n: self.states.__setitem__(n, msg.goal_state.label), depth)
        self.decisions_pub = self.node.create_publisher(String, DECISIONS, depth)
        self.mode_pub = self.node.create_publisher(String, MODE, depth)
        self.ack_pub = self.node.create_publisher(String, ACK, latched)
        self.node.create_subscription(String, TICK, self._on_tick, depth)
        self._clients: dict[tuple[str, str], Any] = {}
        self._String = String
        if clock == "timer":
            self.node.create_timer(float(arch.runtime.period_s), self._on_timer)

    # ------------------------------------------------------------------ setup
    def _client(self, node: str, kind: str) -> Any:
        key = (node, kind)
        if key not in self._clients:
            name = {"ChangeState": "change_state", "GetState": "get_state",
                    "SetParameters": "set_parameters"}[kind]
            self._clients[key] = self.node.create_client(self._types[kind], f"/{node}/{name}")
        return self._clients[key]

    def _call(self, client: Any, request: Any) -> Any:
        """A service call waited for here (setup only: the executor is not spinning yet)."""
        import rclpy

        future = client.call_async(request)
        rclpy.spin_until_future_complete(self.node, future, timeout_sec=self.timeout_s)
        if not future.done():
            raise Ros2Error(f"{client.srv_name}: no answer in {self.timeout_s:g} s")
        return future.result()

    def start(self) -> None:
        """Find the lifecycle nodes and bring them to the loop's configuration.

        A node whose ``get_state`` service does not appear within the service
        timeout is taken as a plain node (parameters only); the lifecycle ones are
        configured and activated or deactivated as the configuration says.

        Raises
        ------
        Ros2Error
            A transition refused or unanswered.
        """
        deadline = time.monotonic() + self.timeout_s
        for n in self.nodes:
            client = self._client(n, "GetState")
            if client.wait_for_service(timeout_sec=max(0.0, deadline - time.monotonic())):
                self.lifecycle.append(n)
                self.states[n] = self._call(client, self._types["GetState"].Request()
                                            ).current_state.label
        for n, what in transitions(self.arch, self.lifecycle, self.states,
                                   self.loop.configuration):
            ok = self._call(self._client(n, "ChangeState"), self._change(what)).success
            if not ok:
                raise Ros2Error(f"/{n}/change_state: {what} refused")
            self.states[n] = _GOAL[what]
        self._publish_ack({"t": None, "ready": True,
                           "configuration": self.loop.configuration})

    def _change(self, what: str) -> Any:
        request = self._types["ChangeState"].Request()
        request.transition.id = _TRANSITION_IDS[what]
        request.transition.label = what
        return request

    # ------------------------------------------------------------------ measurements
    def _store(self, store: dict[str, dict[str, Any]], m: str, s: str, value: Any) -> None:
        store.setdefault(m, {})[s] = value
        self._heard()

    def _on_health(self, m: str, why: str) -> None:
        self.health[m] = why or None
        self._heard()

    def _heard(self) -> None:
        self.received += 1
        self._last_heard = time.monotonic()
        if self._tick is not None and self.received >= self._tick["count"]:
            self._cycle(self._tick)

    def _on_tick(self, msg: Any) -> None:
        tick = json.loads(msg.data)
        self._last_heard = time.monotonic()
        if tick.get("end"):
            self.ended = tick
            return
        tick["received_at"] = time.perf_counter()
        self._tick = tick
        if self.received >= tick["count"]:
            self._cycle(tick)

    def _on_timer(self) -> None:
        self._cycle({"t": self._now(), "received_at": time.perf_counter()})

    def _now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ cycle
    def _cycle(self, tick: dict[str, Any]) -> None:
        self._tick = None
        if self._pending:  # the last commands are still being answered
            if self.clock == "tick":  # a lock-step plant waits for the answer: cannot be
                raise Ros2Error("a tick arrived before the last commands were answered")
            self.stats["skipped"] += 1  # the next timer's cycle catches up (LiveLoop)
            return
        self.stats["ticks"] += 1
        cycles = self.loop.mapek.cycle
        seen = configuration_of(self.arch, self.states, self.loop.configuration) \
            if self.lifecycle else None
        commands = self.loop.push(float(tick["t"]), self.outputs, self.signals, self.health,
                                  seen)
        if self.loop.mapek.cycle != cycles:
            record = document(DecisionRecordDoc, self.loop.decisions[-1])
            self.decisions_pub.publish(self._String(data=json.dumps(record)))
        self.stats["cycle_ms"].append((time.perf_counter() - tick["received_at"]) * 1e3)
        self._ack = {"t": tick["t"], "configuration": self.loop.configuration,
                     "commands": [c.to_dict() for c in commands],
                     "received_at": tick["received_at"]}
        for c in commands:
            self._act(c)
        if not self._pending:
            self._answer()

    def _act(self, c: Command) -> None:
        part, mode = c.ros2_mode(self.arch.name)
        self.mode_pub.publish(self._String(data=json.dumps(
            {"t_s": c.t_s, "part": part, "mode": mode, "action": c.action})))
        if c.kind == "configuration":
            states = dict(self.states)
            for n, what in transitions(self.arch, self.lifecycle, states, c.configuration):
                self._request(n, "ChangeState", self._change(what),
                              lambda ok, n=n, what=what: self._changed(n, what, ok))
            return
        if c.module not in self.nodes:
            self.stats["refused"].append(f"{c.action}: {c.module} is not a node")
            return
        from rclpy.parameter import Parameter

        request = self._types["SetParameters"].Request()
        request.parameters = [Parameter(k, value=parameter_value(v)).to_parameter_msg()
                              for k, v in c.values.items()]
        self._request(c.module, "SetParameters", request,
                      lambda ok, c=c: ok or self.stats["refused"].append(
                          f"{c.action}: /{c.module}/set_parameters refused"))

    def _changed(self, n: str, what: str, ok: bool) -> None:
        if ok:
            self.states[n] = _GOAL[what]
        else:
            self.stats["refused"].append(f"/{n}/change_state: {what} refused")

    def _request(self, node: str, kind: str, request: Any, done: Any) -> None:
        self._pending += 1
        future = self._client(node, kind).call_async(request)

        def finish(f: Any) -> None:
            result = f.result()
            ok = bool(getattr(result, "success", False)) if kind == "ChangeState" else all(
                r.successful for r in result.results)
            done(ok)
            self._pending -= 1
            if not self._pending:
                self._answer()

        future.add_done_callback(finish)

    def _answer(self) -> None:
        ack, self._ack = self._ack, None
        if ack is None:
            return
        if ack["commands"]:
            self.stats["act_ms"].append((time.perf_counter() - ack["received_at"]) * 1e3)
        del ack["received_at"]
        self._publish_ack(ack)

    def _publish_ack(self, ack: dict[str, Any]) -> None:
        self.ack_pub.publish(self._String(data=json.dumps(jsonable(ack))))

    # ------------------------------------------------------------------ results
    def summary(self) -> dict[str, Any]:
        """Cycles, measurements and the timings of the bridge (ms)."""
        def pct(xs: list[float]) -> dict[str, float] | None:
            if not xs:
                return None
            a = np.asarray(xs)
            return {"n": int(a.size), "mean": float(a.mean()),
                    "p50": float(np.percentile(a, 50)), "p95": float(np.percentile(a, 95)),
                    "max": float(a.max())}

        return {"cycles": self.loop.mapek.cycle, "ticks": self.stats["ticks"],
                "messages": self.received, "cycle_ms": pct(self.stats["cycle_ms"]),
                "act_ms": pct(self.stats["act_ms"]), "refused": list(self.stats["refused"]),
                "skipped": self.stats["skipped"],
                "lifecycle_nodes": list(self.lifecycle)}

    def destroy(self) -> None:
        """Destroy the node (rclpy itself stays initialized)."""
        self.node.destroy_node()


def run_bridge(bridge: Ros2Bridge, *, timeout_s: float = 30.0,
               until: Any = None) -> dict[str, Any]:
    """Spin ``bridge`` until the plant ends the run (``clock="tick"``) or ``until()`` is true.

    Returns
    -------
    dict
        :meth:`Ros2Bridge.summary` with ``wall_s``, ``cpu_s`` (this process),
        ``cpu_percent`` and ``messages_per_s``, and ``plant`` (what the plant's end
        tick carried, or None). Ctrl-C ends the spin and returns the same.

    Raises
    ------
    Ros2Error
        Silence from the plant for ``timeout_s`` (never a hang).
    """
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor()
    executor.add_node(bridge.node)
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        while bridge.ended is None and not (until is not None and until()):
            executor.spin_once(timeout_sec=0.1)
            if time.monotonic() - bridge._last_heard > timeout_s:
                raise Ros2Error(f"no measurement for {timeout_s:g} s; the plant fell silent")
    except KeyboardInterrupt:  # Ctrl-C ends a run on a robot: the summary and log follow
        pass
    finally:
        executor.remove_node(bridge.node)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    out = bridge.summary()
    out.update(wall_s=wall, cpu_s=cpu, cpu_percent=100.0 * cpu / wall if wall else math.nan,
               messages_per_s=bridge.received / wall if wall else math.nan,
               plant=(bridge.ended or {}).get("stats"))
    return out
