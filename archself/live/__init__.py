"""Live mode: the MAPE-K loop on a real plant instead of the simulator.

The plant's code pushes measurements (:meth:`LiveLoop.push`) and receives
reconfiguration commands (:class:`Command`: a return value, callbacks and a
queue); the MAPE-K loop (:class:`archself.runtime.MapeK`) runs unchanged on a
:class:`MeasuredSystem`, which implements the live-system contract from the
measurements and the architecture's compiled models. Δ and the stability test
come from those models (no snapshot of a real plant exists); an architecture
whose actions only a rollout could judge is refused (:func:`live_problems`).
:mod:`archself.live.wire` puts the plant in another process, over a loopback
socket (``archself live ARCH --connect HOST:PORT``). See docs/live.md.

==========================  ===================================================
name                        what it is
==========================  ===================================================
:class:`LiveLoop`           measurements in, commands out; owns the MAPE-K loop
:class:`Command`            one reconfiguration the plant is told to make
:class:`MeasuredSystem`     the live-system contract over pushed measurements
:class:`ModelSnapshot`      a copy of the compiled models, for the stability test
:func:`live_problems`       the actions only a rollout could judge
:class:`LiveError`          what live mode refuses (one-line message)
:class:`PlantLink`          the plant's end of the socket
:func:`run_remote`          the loop's end of the socket
==========================  ===================================================
"""

from __future__ import annotations

from archself.live.loop import Command, LiveLoop, live_problems
from archself.live.system import NO_ROLLOUT, LiveError, MeasuredSystem, ModelSnapshot
from archself.live.wire import PlantLink, parse_address, run_remote

__all__ = [
    "NO_ROLLOUT",
    "Command",
    "LiveError",
    "LiveLoop",
    "MeasuredSystem",
    "ModelSnapshot",
    "PlantLink",
    "live_problems",
    "parse_address",
    "run_remote",
]
