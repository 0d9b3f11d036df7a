"""A stand-in for a real plant: archself's simulator in its own process, behind a socket.

It compiles the architecture with a scenario's faults (the physical modules and the
control software of the running configuration), listens on a loopback port, and once
the MAPE-K loop has connected (``python examples/live/loop.py`` or ``archself live``)
it steps, pushes a measurement every ``--push-every`` steps and applies the commands
the loop answers with, before its next step. The loop process has no simulator: it
sees only these measurements.

    python examples/live/plant_process.py architectures/process_plant.yaml \
        --scenario drift_then_valve --duration 240

The first line on stdout is ``listening on HOST:PORT token TOKEN`` (the loop passes
the token: ``--token`` or ``ARCHSELF_LIVE_TOKEN``); the last is a JSON summary of
the commands applied. See docs/live.md.
"""

from __future__ import annotations

import argparse
import json
import sys

from archself.errors import ArchselfError
from archself.live import PlantLink
from archself.model.loader import load_architecture
from archself.system.live import compile_system


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("arch", help="architecture file")
    p.add_argument("--scenario", required=True, help="scenario of the file (its faults)")
    p.add_argument("--seed", type=int, default=None, help="default: the scenario's")
    p.add_argument("--duration", type=float, default=None, help="s (default: the scenario's)")
    p.add_argument("--host", default="127.0.0.1", help="loopback address to listen on")
    p.add_argument("--port", type=int, default=0, help="0: any free port")
    p.add_argument("--push-every", type=int, default=1, help="steps between measurements")
    p.add_argument("--timeout", type=float, default=30.0, help="s to wait for the loop")
    args = p.parse_args(argv)

    arch = load_architecture(args.arch).arch
    sc = arch.scenarios[args.scenario]
    seed = sc.seed if args.seed is None else args.seed
    plant = compile_system(arch, seed=seed, scenario=sc)
    steps = int(round((args.duration or sc.duration_s) / plant.dt))
    applied = []
    with PlantLink(args.host, args.port, timeout_s=args.timeout) as link:
        print(f"listening on {link.host}:{link.port} token {link.token}", flush=True)
        link.accept()
        for k in range(1, steps + 1):
            plant.step()
            if k % args.push_every:
                continue
            commands = link.send(plant.t, plant.outputs, plant.local_signals(),
                                 plant.health(), plant.configuration)
            for c in commands:  # applied before the next step, as in simulation
                if c.kind == "configuration":
                    plant.apply_configuration(c.configuration)
                else:
                    plant.set_params(c.module, c.values)
                applied.append({"t_s": plant.t, **c.to_dict()})
    print(json.dumps({"steps": steps, "configuration": plant.configuration,
                      "applied": applied}))
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except ArchselfError as exc:  # no loop came, it fell silent, ...: one line, exit 1
        print(f"plant: {exc}", file=sys.stderr)
        sys.exit(1)
