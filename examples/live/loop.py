"""The MAPE-K loop of a plant in another process (``plant_process.py``), over a socket.

    python examples/live/loop.py architectures/process_plant.yaml --connect 127.0.0.1:PORT

No simulator runs here: the loop sees the plant's measurements only, and takes Δ
and stability from the architecture's compiled models. ``archself live`` is the
same as a command. See docs/live.md.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from archself.errors import ArchselfError
from archself.live import LiveLoop, parse_address, run_remote
from archself.model.loader import load_architecture


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arch", help="architecture file")
    p.add_argument("--connect", required=True, metavar="HOST:PORT", help="the plant")
    p.add_argument("--token", default=os.environ.get("ARCHSELF_LIVE_TOKEN"),
                   help="the token the plant printed (default: $ARCHSELF_LIVE_TOKEN)")
    p.add_argument("--timeout", type=float, default=30.0, help="s of silence before giving up")
    args = p.parse_args(argv)

    arch = load_architecture(args.arch).arch
    loop = LiveLoop(arch)
    loop.on_command(lambda c: print(f"t = {c.t_s:g} s: {c.kind} {c.previous} -> "
                                    f"{c.configuration} ({c.action})", file=sys.stderr))
    host, port = parse_address(args.connect)
    served = run_remote(loop, host, port, timeout_s=args.timeout, token=args.token)
    print(json.dumps({"measurements": served, "switches": loop.switches,
                      "updates": loop.updates}))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ArchselfError as exc:
        print(f"loop: {exc}", file=sys.stderr)
        sys.exit(1)
