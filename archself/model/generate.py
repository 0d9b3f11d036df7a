"""Generate large DAG-like architecture files (for scaling studies and benchmarks).

The graph is layered: module ``m{i}`` receives edges from up to ``fan_in``
modules in earlier layers, so W is nilpotent (ρ(W) = 0) unless ``feedback``
adds a few weak backward edges, which keep ρ(W) well below 1. The relays are
unit delays, so feedback edges make no algebraic loop.

The text is JSON laid out one module or edge a line, after a YAML comment line:
valid YAML 1.2 (which includes JSON) that the loader parses with the json module,
so that a 10^5-module file (about 22 MB) loads in seconds and stays under the
size caps (``archself.io.yaml_source``: 8 MiB of YAML, 64 MiB of JSON).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def generate_architecture(
    n: int,
    *,
    seed: int = 0,
    fan_in: int = 3,
    feedback: int = 0,
    name: str | None = None,
    scenarios: dict[str, Any] | None = None,
) -> str:
    """YAML text of a valid architecture with ``n`` ``generic.relay`` modules.

    Parameters
    ----------
    n : int
        Number of modules (≥ 2).
    seed : int
        Seed of the random wiring.
    fan_in : int
        Maximum number of incoming edges per module.
    feedback : int
        Number of weak backward edges (cycles).
    name : str, optional
        The file's ``name`` (default ``generated-N``).
    scenarios : dict, optional
        ``scenarios`` of the file, as data (written as JSON).

    Examples
    --------
    >>> text = generate_architecture(5, seed=1)
    >>> text.splitlines()[0].startswith("# yaml-language-server")
    True
    """
    if n < 2:
        raise ValueError("n must be at least 2")
    import json

    rng = np.random.default_rng(seed)
    width = max(1, int(np.sqrt(n)))
    lines = [
        "# yaml-language-server: $schema=../schemas/architecture.schema.json",
        f'{{"archself": 1, "name": {json.dumps(name or f"generated-{n}")},',
        ' "modules": {',
    ]
    mods = [
        f' "m{i}": {{"kind": "{"physical" if i < width else "functional"}", '
        '"type": "generic.relay", "residual": {"signal": "deviation", "nominal": 0.1}}'
        for i in range(n)
    ]
    lines.append(",\n".join(mods))
    edges: list[str] = []
    for i in range(width, n):
        earlier = np.arange(0, (i // width) * width)  # every module of the earlier layers
        k = min(int(rng.integers(1, fan_in + 1)), len(earlier))
        sources = set(rng.choice(earlier, size=k, replace=False).tolist())
        if i < 2 * width:  # columns c and c+1 of the first layer: the graph is connected
            sources |= {i - width, (i - width + 1) % width}
        w = 0.9 / len(sources)
        for s in sorted(int(x) for x in sources):
            edges.append(
                f' {{"from": "m{s}", "to": "m{i}", "weight": {w:.4f}, "carries": "signal"}}'
            )
    backward: set[tuple[int, int]] = set()
    for _ in range(feedback):
        a, b = sorted(int(x) for x in rng.choice(n, size=2, replace=False))
        if (b, a) not in backward:
            backward.add((b, a))
            edges.append(f' {{"from": "m{b}", "to": "m{a}", "weight": 0.01, "carries": "signal"}}')
    lines += [" },", ' "edges": [', ",\n".join(edges), " ],"]
    lines += [
        ' "configurations": {"all": {"initial": true, "modules": ['
        + ", ".join(f'"m{i}"' for i in range(n)) + "]}},",
        ' "runtime": {"step_s": 0.1, "period_s": 1.0,',
        f'  "objective": {{"actual": "m{n - 1}.signal", "reference": "m0.signal"}},',
        '  "top_k": 5, "cost_weight": 0.1,',
        '  "stability": {"margin": 0.001, "lyapunov_alpha": 0.01, "horizon_steps": 10}}'
        + (f',\n "scenarios": {json.dumps(scenarios)}' if scenarios else "") + "}",
    ]
    return "\n".join(line for line in lines if line) + "\n"
