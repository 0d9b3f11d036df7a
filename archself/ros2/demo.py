"""A simulated robot on ROS 2: the plant node and the functional modules as lifecycle nodes.

:class:`DemoPlant` steps an architecture's compiled simulated system
(:func:`archself.system.live.compile_system` with a scenario's faults: the
same modules ``archself simulate`` steps) and publishes, every ``runtime.period_s``,
each module output, residual signal and health on the topics of
:mod:`archself.ros2.topics`, then a tick, and waits for the loop's answer (lock
step: the run is the simulation's, whatever the machine's load). Each node module
(the functional ones by default) is an ``rclpy.lifecycle`` node of its own name
holding the file's parameters as ROS 2 parameters; the plant runs the
configuration whose nodes are active (it follows their ``transition_event``
topics) and applies the parameter changes the nodes announce on
``/parameter_events``. The modules' computation stays inside the plant's compiled
system, so the run can be compared with ``archself simulate`` step for step.

Run it as its own process (the bridge is the other one)::

    python -m archself.ros2.demo ARCH --scenario imu_drift [--seed N] [--duration S]
        [--rate SIM_S_PER_S] [--free] [--linger S] [--nodes M1,M2] [--timeout S]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from archself.errors import ArchselfError
from archself.model.architecture import Architecture
from archself.model.loader import load_architecture
from archself.reports.export import node_modules
from archself.ros2.base import Ros2Error, require_rclpy
from archself.ros2.topics import (
    ACK,
    TICK,
    configuration_of,
    health_topic,
    output_topic,
    parameter_value,
    residual_topic,
)

__all__ = ["DemoPlant", "main", "module_node"]


def module_node(arch: Architecture, module: str) -> Any:
    """A lifecycle node named ``module`` that declares the module's parameters (nominal values)."""
    require_rclpy()
    from rclpy.lifecycle import LifecycleNode

    node = LifecycleNode(module)
    for k, p in arch.modules[module].params.items():
        node.declare_parameter(k, parameter_value(p.value))
    return node


def _numeric(v: Any) -> bool:
    if isinstance(v, (bool, str)) or v is None:
        return False
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return False
    return a.ndim <= 2


class DemoPlant:
    """The simulated plant as a ROS 2 node, in lock step with the bridge.

    Parameters
    ----------
    arch : Architecture
    scenario : str
        A scenario of the file (its faults are injected).
    seed : int, optional
        Default: the scenario's.
    duration_s : float, optional
        Default: the scenario's.
    nodes : list of str, optional
        The modules that are lifecycle nodes (default: the functional ones).
    timeout_s : float
        Longest wait for the loop's answer or a node's transition.
    linger_s : float
        Seconds the nodes stay up after the run (for a client to look at them).
    rate : float, optional
        Simulated seconds per wall-clock second (1: real time); default: as fast
        as the loop answers.
    free : bool
        Do not wait for the loop: publish every step with the simulated time on
        ``/clock`` (for a bridge with ``clock="timer"`` on ``use_sim_time``) and
        follow the nodes' states as they change, as a robot does.
    """

    def __init__(self, arch: Architecture, scenario: str, *, seed: int | None = None,
                 duration_s: float | None = None, nodes: Sequence[str] | None = None,
                 timeout_s: float = 30.0, linger_s: float = 0.0,
                 rate: float | None = None, free: bool = False) -> None:
        rclpy = require_rclpy()
        from lifecycle_msgs.msg import TransitionEvent
        from rcl_interfaces.msg import ParameterEvent
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import Float64, Float64MultiArray, String

        from archself.system.live import compile_system

        if scenario not in arch.scenarios:
            raise Ros2Error(f"{arch.name}: no scenario {scenario!r}; "
                            f"scenarios: {', '.join(arch.scenarios)}")
        sc = arch.scenarios[scenario]
        self.arch = arch
        self.seed = int(sc.seed if seed is None else seed)
        self.duration_s = float(sc.duration_s if duration_s is None else duration_s)
        self.timeout_s = float(timeout_s)
        self.linger_s = float(linger_s)
        self.rate = None if not rate else float(rate)
        self.free = bool(free)
        self.plant = compile_system(arch, seed=self.seed, scenario=sc)
        self.nodes = node_modules(arch, list(nodes) if nodes is not None else None)
        if not rclpy.ok():
            rclpy.init()
        self.node = rclpy.create_node("archself_plant")
        self.module_nodes = [module_node(arch, n) for n in self.nodes]
        self.states = {n: "unconfigured" for n in self.nodes}
        self.params: list[tuple[str, dict[str, Any]]] = []
        self.acks: list[dict[str, Any]] = []
        depth = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._Float64, self._Array, self._String = Float64, Float64MultiArray, String
        self._pubs: dict[str, Any] = {}
        self.tick_pub = self.node.create_publisher(String, TICK, depth)
        if free:
            from rosgraph_msgs.msg import Clock

            self._Clock = Clock
            self.clock_pub = self.node.create_publisher(Clock, "/clock", depth)
        self.node.create_subscription(String, ACK, lambda m: self.acks.append(
            json.loads(m.data)), latched)
        for n in self.nodes:
            self.node.create_subscription(
                TransitionEvent, f"/{n}/transition_event",
                lambda msg, n=n: self.states.__setitem__(n, msg.goal_state.label), depth)
        self.node.create_subscription(ParameterEvent, "/parameter_events",
                                      self._on_parameters, depth)
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor()
        for n in (self.node, *self.module_nodes):
            self.executor.add_node(n)
        self.published = 0
        self.round_trip_ms: list[float] = []
        self.switches: list[dict[str, Any]] = []

    def _on_parameters(self, msg: Any) -> None:
        from rclpy.parameter import parameter_value_to_python

        name = msg.node.lstrip("/")
        if name in self.nodes:
            values = {p.name: parameter_value_to_python(p.value)
                      for p in (*msg.new_parameters, *msg.changed_parameters)}
            if values:
                self.params.append((name, values))

    def _publisher(self, topic: str, kind: Any) -> Any:
        if topic not in self._pubs:
            from rclpy.qos import QoSProfile, ReliabilityPolicy

            self._pubs[topic] = self.node.create_publisher(
                kind, topic, QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE))
        return self._pubs[topic]

    def _measure(self) -> list[tuple[Any, Any]]:
        """What one measurement publishes: ``(publisher, message)`` pairs."""
        from archself.ros2.bridge import array_msg

        p = self.plant
        out: list[tuple[Any, Any]] = []
        for m, sigs in p.outputs.items():
            for s, v in sigs.items():
                if _numeric(v):
                    out.append((self._publisher(output_topic(m, s), self._Array), array_msg(v)))
        signals = p.local_signals()
        for m, mod in self.arch.modules.items():
            if mod.residual is not None and m in signals:
                v = signals[m].get(mod.residual.signal)
                out.append((self._publisher(residual_topic(m, mod.residual.signal),
                                            self._Float64),
                            self._Float64(data=math.nan if v is None else float(v))))
        for m, why in p.health().items():
            out.append((self._publisher(health_topic(m), self._String),
                        self._String(data=why or "")))
        return out

    def _spin_until(self, done: Any, what: str) -> None:
        deadline = time.monotonic() + self.timeout_s
        while not done():
            if time.monotonic() > deadline:
                raise Ros2Error(f"plant: {what} did not come in {self.timeout_s:g} s")
            self.executor.spin_once(timeout_sec=0.05)

    def _wait_for_bridge(self) -> dict[str, Any]:
        """Wait for the bridge's ready answer and for its subscriptions to every topic."""
        self._spin_until(lambda: any(a.get("ready") for a in self.acks), "the loop's ready")
        ready = next(a for a in self.acks if a.get("ready"))
        self.acks.clear()
        pubs = [pub for pub, _ in self._measure()] + [self.tick_pub]
        self._spin_until(lambda: all(pub.get_subscription_count() > 0 for pub in pubs),
                         "the loop's subscriptions")
        return ready

    def _follow(self, ack: dict[str, Any]) -> None:
        """Apply what the loop commanded, as the nodes show it (lifecycle states, parameters)."""
        conf = ack["configuration"]
        if conf != self.plant.configuration:
            self._spin_until(lambda: configuration_of(self.arch, self.states, conf) == conf,
                             f"the lifecycle states of configuration {conf}")
            self.switches.append({"t_s": float(self.plant.t), "from": self.plant.configuration,
                                  "to": conf})
            self.plant.apply_configuration(conf)
        wanted = [c for c in ack["commands"] if c["kind"] == "parameters"]
        for c in wanted:
            def seen(c: dict[str, Any] = c) -> bool:  # one event per parameter set
                got = {k for n, v in self.params if n == c["module"] for k in v}
                return set(c["values"]) <= got
            self._spin_until(seen, f"the parameter event of {c['module']}")
        for n, values in self.params:
            self.plant.set_params(n, values)
        self.params.clear()

    def run(self) -> dict[str, Any]:
        """Step the scenario to its end in lock step with the loop; return the plant's stats."""
        ready = self._wait_for_bridge()
        self._spin_until(
            lambda: configuration_of(self.arch, self.states, ready["configuration"])
            == ready["configuration"], "the initial lifecycle states")
        self.params.clear()  # the declarations at start
        if self.free:
            return self._run_free()
        period = float(self.arch.runtime.period_s)
        steps = max(1, round(period / self.plant.dt))
        eps = 1e-9 * self.plant.dt
        wall0, t0_sim = time.monotonic(), float(self.plant.t)
        while self.plant.t < self.duration_s - eps:
            for _ in range(steps):
                self.plant.step()
            if self.rate is not None:
                ahead = wall0 + (self.plant.t - t0_sim) / self.rate - time.monotonic()
                if ahead > 0:
                    time.sleep(ahead)
            pairs = self._measure()
            t0 = time.perf_counter()
            for pub, msg in pairs:
                pub.publish(msg)
            self.published += len(pairs)
            self.tick_pub.publish(self._String(data=json.dumps(
                {"t": float(self.plant.t), "count": self.published})))
            t = float(self.plant.t)
            self._spin_until(lambda t=t: any(a.get("t") == t for a in self.acks),
                             f"the loop's answer at t = {t:g} s")
            self.round_trip_ms.append((time.perf_counter() - t0) * 1e3)
            ack = next(a for a in self.acks if a.get("t") == t)
            self.acks.clear()
            self._follow(ack)
        return self._end({"measurements": len(self.round_trip_ms), "published": self.published,
                          "round_trip_ms": _percentiles(self.round_trip_ms),
                          "switches": self.switches})

    def _run_free(self) -> dict[str, Any]:
        """Step and publish every step on the simulated clock; follow the nodes meanwhile."""
        eps = 1e-9 * self.plant.dt
        wall0, t0_sim, n = time.monotonic(), float(self.plant.t), 0
        while self.plant.t < self.duration_s - eps:
            self.executor.spin_once(timeout_sec=0.0)
            conf = configuration_of(self.arch, self.states, self.plant.configuration)
            if conf is not None and conf != self.plant.configuration:
                self.switches.append({"t_s": float(self.plant.t),
                                      "from": self.plant.configuration, "to": conf})
                self.plant.apply_configuration(conf)
            for name, values in self.params:
                self.plant.set_params(name, values)
            self.params.clear()
            self.plant.step()
            n += 1
            pairs = self._measure()
            for pub, msg in pairs:
                pub.publish(msg)
            self.published += len(pairs)
            clock = self._Clock()
            ns = int(round(self.plant.t * 1e9))
            clock.clock.sec, clock.clock.nanosec = ns // 10**9, ns % 10**9
            self.clock_pub.publish(clock)
            if self.rate is not None:
                ahead = wall0 + (self.plant.t - t0_sim) / self.rate - time.monotonic()
                if ahead > 0:
                    time.sleep(ahead)
        return self._end({"measurements": n, "published": self.published,
                          "round_trip_ms": None, "switches": self.switches})

    def _end(self, stats: dict[str, Any]) -> dict[str, Any]:
        """Tell the loop the run is over; keep the nodes up ``linger_s``."""
        self.tick_pub.publish(self._String(data=json.dumps({"end": True, "stats": stats})))
        end = time.monotonic() + max(self.linger_s, 0.2)  # the end tick leaves first
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)
        return stats


def _percentiles(xs: list[float]) -> dict[str, float] | None:
    if not xs:
        return None
    a = np.asarray(xs)
    return {"n": int(a.size), "mean": float(a.mean()), "p50": float(np.percentile(a, 50)),
            "p95": float(np.percentile(a, 95)), "max": float(a.max())}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m archself.ros2.demo ARCH --scenario S``: run the demo plant (exit 1 on error)."""

    ap = argparse.ArgumentParser(prog="python -m archself.ros2.demo")
    ap.add_argument("arch")
    ap.add_argument("--scenario", required=True)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--duration", type=float)
    ap.add_argument("--nodes")
    ap.add_argument("--timeout", type=float, default=30.0)
    ap.add_argument("--linger", type=float, default=0.0)
    ap.add_argument("--rate", type=float)
    ap.add_argument("--free", action="store_true")
    args = ap.parse_args(argv)
    try:
        arch = load_architecture(args.arch).arch
        nodes = args.nodes.split(",") if args.nodes else None
        plant = DemoPlant(arch, args.scenario, seed=args.seed, duration_s=args.duration,
                          nodes=nodes, timeout_s=args.timeout, linger_s=args.linger,
                          rate=args.rate, free=args.free)
        stats = plant.run()
    except ArchselfError as exc:
        print(f"{args.arch}: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(stats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
