"""A plain rclpy client (no archself import): watches lifecycle states and a parameter.

``python ros2_plain_client.py NODE1,NODE2,... PARAM_NODE PARAM1,PARAM2 SECONDS``
polls ``/<node>/get_state`` (lifecycle_msgs/srv/GetState) of each node and
``/<param node>/get_parameters`` (rcl_interfaces/srv/GetParameters) every 0.1 s
until SECONDS have passed or the nodes are gone after having been seen, and prints
one JSON object: every distinct ``{node: state label}`` and every distinct
``{param: value}`` seen, in order.
"""

import json
import sys
import time

import rclpy
from lifecycle_msgs.srv import GetState
from rcl_interfaces.srv import GetParameters
from rclpy.parameter import parameter_value_to_python


def _call(node, client, request, timeout=1.0):
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    return future.result() if future.done() else None


def main() -> None:
    nodes, param_node, params, seconds = sys.argv[1].split(","), sys.argv[2], \
        sys.argv[3].split(","), float(sys.argv[4])
    rclpy.init()
    me = rclpy.create_node("plain_client")
    states = {n: me.create_client(GetState, f"/{n}/get_state") for n in nodes}
    getp = me.create_client(GetParameters, f"/{param_node}/get_parameters")
    seen_states, seen_params, was_up = [], [], False
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        up = getp.service_is_ready() and all(c.service_is_ready() for c in states.values())
        if not up:
            if was_up:
                break  # the robot's nodes are gone: the run is over
            rclpy.spin_once(me, timeout_sec=0.1)
            continue
        was_up = True
        snap = {}
        for n, c in states.items():
            r = _call(me, c, GetState.Request())
            snap[n] = r.current_state.label if r is not None else None
        if None not in snap.values() and (not seen_states or seen_states[-1] != snap):
            seen_states.append(snap)
        r = _call(me, getp, GetParameters.Request(names=params))
        if r is not None and len(r.values) == len(params):
            vals = {p: parameter_value_to_python(v) for p, v in zip(params, r.values,
                                                                        strict=True)}
            if not seen_params or seen_params[-1] != vals:
                seen_params.append(vals)
        time.sleep(0.1)
    print(json.dumps({"states": seen_states, "params": seen_params}))
    me.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
