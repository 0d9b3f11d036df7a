"""A plant and its MAPE-K loop in two processes: JSON lines over a local socket.

The plant listens (:class:`PlantLink`), the loop connects (:func:`run_remote`);
each message is one JSON object on one line (UTF-8, at most
:data:`MAX_MESSAGE` bytes; non-finite numbers are ``null``, as JSON has no NaN):

==============  =========  ==========================================================
message         direction  fields
==============  =========  ==========================================================
``hello``       loop →     ``protocol`` (1), ``architecture`` (the file's ``name``)
``measurement`` plant →    ``t``, ``outputs``, ``signals``, ``health``, ``configuration``
                           (:meth:`archself.live.MeasuredSystem.update`)
``commands``    loop →     ``t``, ``commands`` (a list of :meth:`Command.to_dict`), the
                           answer to every measurement, usually empty
``end``         plant →    the run is over; the loop returns
==============  =========  ==========================================================

The loop answers every measurement, so a plant that waits for the answer before
its next step (:meth:`PlantLink.send`) acts on a decision at the same step a
simulation would; a plant that does not wait reads the answers later and acts
that much later. There is no authentication or encryption: the plant binds to a
loopback address only (:class:`PlantLink` refuses any other), and a remote loop
reaches it through a tunnel (``ssh -L``) if at all.
"""

from __future__ import annotations

import ipaddress
import json
import socket
from collections.abc import Mapping
from typing import Any

from archself.io.jsondata import jsonable
from archself.live.loop import Command, LiveLoop
from archself.live.system import LiveError

__all__ = ["MAX_MESSAGE", "PROTOCOL", "PlantLink", "measured", "parse_address", "run_remote"]

#: Version of the message set above.
PROTOCOL = 1
#: Longest message accepted (bytes, newline included).
MAX_MESSAGE = 8 * 1024 * 1024


def parse_address(text: str) -> tuple[str, int]:
    """``"HOST:PORT"`` → ``(host, port)`` (``[::1]:PORT`` for IPv6).

    Examples
    --------
    >>> parse_address("127.0.0.1:5555")
    ('127.0.0.1', 5555)
    >>> parse_address("[::1]:80")
    ('::1', 80)
    """
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise LiveError(f"address {text!r} is not HOST:PORT")
    return host.strip("[]"), int(port)


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IP addresses.

    Examples
    --------
    >>> is_loopback("127.0.0.1"), is_loopback("::1"), is_loopback("10.0.0.1")
    (True, True, False)
    """
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def measured(outputs: Mapping[str, Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """The numeric part of a system's outputs as plain JSON data (models etc. left out).

    Examples
    --------
    >>> import numpy as np
    >>> measured({"a": {"x": np.array([1.0, np.nan]), "m": object(), "y": None}})
    {'a': {'x': [1.0, None], 'y': None}}
    """
    out: dict[str, dict[str, Any]] = {}
    for m, sigs in outputs.items():
        row: dict[str, Any] = {}
        for k, v in (sigs or {}).items():
            if v is None or isinstance(v, (int, float)) or (
                hasattr(v, "dtype") and getattr(v.dtype, "kind", "") in "fiub"
            ):
                row[str(k)] = jsonable(v)
        out[str(m)] = row
    return out


def _encode(msg: Mapping[str, Any]) -> bytes:
    return (json.dumps(jsonable(msg), separators=(",", ":"), allow_nan=False) + "\n").encode()


class _Channel:
    """One connected socket: send a message, read the next one (bounded in size and time)."""

    def __init__(self, sock: socket.socket, timeout_s: float | None) -> None:
        sock.settimeout(timeout_s)
        self.sock = sock
        self.file = sock.makefile("rb")
        self.timeout_s = timeout_s

    def send(self, msg: Mapping[str, Any]) -> None:
        self.sock.sendall(_encode(msg))

    def read(self) -> dict[str, Any] | None:
        """The next message, or None when the peer closed the connection."""
        try:
            line = self.file.readline(MAX_MESSAGE + 1)
        except TimeoutError:
            raise LiveError(f"no message from the peer for {self.timeout_s:g} s") from None
        if not line:
            return None
        if len(line) > MAX_MESSAGE:
            raise LiveError(f"message longer than {MAX_MESSAGE} bytes")
        try:
            msg = json.loads(line.decode("utf-8"))  # UTF-8 only (not guessed from a BOM)
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise LiveError(f"malformed message: {exc}") from None
        except RecursionError:
            raise LiveError("malformed message: nested too deeply") from None
        if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
            raise LiveError("malformed message: not an object with a 'type'")
        return msg

    def close(self) -> None:
        try:
            self.file.close()
        finally:
            self.sock.close()


class PlantLink:
    """The plant's end: listen on a loopback port, wait for the loop, exchange messages.

    Parameters
    ----------
    host : str, optional
        A loopback address (default ``127.0.0.1``); others are refused.
    port : int, optional
        Port to listen on (0: a free one, see :attr:`port`).
    timeout_s : float, optional
        Longest wait for the loop to connect or answer (a hang guard), default 30.

    Examples
    --------
    >>> link = PlantLink(port=0)                         # doctest: +SKIP
    >>> print(link.port, flush=True)                     # doctest: +SKIP
    >>> link.accept()                                    # doctest: +SKIP
    >>> commands = link.send(t, outputs=..., signals=..., health=..., configuration=c)
    ...                                                  # doctest: +SKIP
    >>> link.close()                                     # doctest: +SKIP
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 30.0) -> None:
        if not is_loopback(host):
            raise LiveError(f"{host}: the plant listens on a loopback address only")
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._server = socket.socket(family, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind((host, int(port)))
        self._server.listen(1)
        self._server.settimeout(timeout_s)
        self.host = host
        self.port = int(self._server.getsockname()[1])
        self.timeout_s = float(timeout_s)
        self._channel: _Channel | None = None
        self.hello: dict[str, Any] | None = None

    def accept(self) -> dict[str, Any]:
        """Wait for the loop to connect; its ``hello`` message.

        Raises
        ------
        LiveError
            No loop within ``timeout_s``, or it did not say hello.
        """
        try:
            sock, _ = self._server.accept()
        except TimeoutError:
            raise LiveError(f"no loop connected within {self.timeout_s:g} s") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._channel = _Channel(sock, self.timeout_s)
        msg = self._channel.read()
        if msg is None or msg.get("type") != "hello":
            raise LiveError("the loop did not say hello")
        self.hello = msg
        return msg

    def send(
        self,
        t: float,
        outputs: Mapping[str, Mapping[str, Any]] | None = None,
        signals: Mapping[str, Mapping[str, Any]] | None = None,
        health: Mapping[str, str | None] | None = None,
        configuration: str | None = None,
    ) -> list[Command]:
        """Send one measurement and wait for the loop's answer (the commands to apply).

        ``outputs`` may be a system's raw outputs: only their numeric part is sent
        (:func:`measured`).
        """
        ch = self._channel
        if ch is None:
            raise LiveError("no loop connected (call accept first)")
        ch.send({
            "type": "measurement",
            "t": float(t),
            "outputs": measured(outputs or {}),
            "signals": signals or {},
            "health": health or {},
            "configuration": configuration,
        })
        msg = ch.read()
        if msg is None:
            raise LiveError("the loop closed the connection")
        if msg.get("type") != "commands":
            raise LiveError(f"expected commands, got {msg.get('type')!r}")
        return [Command.from_dict(c) for c in msg.get("commands") or []]

    def close(self) -> None:
        """Tell the loop the run is over and close the connection and the port."""
        try:
            if self._channel is not None:
                try:
                    self._channel.send({"type": "end"})
                except OSError:
                    pass
                self._channel.close()
        finally:
            self._server.close()

    def __enter__(self) -> PlantLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def run_remote(loop: LiveLoop, host: str, port: int, *, timeout_s: float = 30.0) -> int:
    """Connect ``loop`` to a plant at ``host:port`` and serve it until it ends the run.

    Every measurement is pushed into the loop (:meth:`LiveLoop.push`) and answered
    with the commands the push gave.

    Parameters
    ----------
    loop : LiveLoop
    host, port : str, int
        The plant's address.
    timeout_s : float
        Longest wait for the connection or for any message (a hang guard).

    Returns
    -------
    int
        The number of measurements served.

    Raises
    ------
    LiveError
        The plant cannot be reached, falls silent for ``timeout_s``, closes the
        connection without ``end``, or sends a malformed message.
    """
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout_s)
    except OSError as exc:
        raise LiveError(f"cannot connect to the plant at {host}:{port}: {exc}") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    ch = _Channel(sock, timeout_s)
    served = 0
    try:
        ch.send({"type": "hello", "protocol": PROTOCOL, "architecture": loop.arch.name})
        while True:
            msg = ch.read()
            if msg is None:
                raise LiveError("the plant closed the connection without ending the run")
            kind = msg["type"]
            if kind == "end":
                return served
            if kind != "measurement":
                raise LiveError(f"unexpected message {kind!r} from the plant")
            commands = loop.push(
                msg.get("t", float("nan")),
                msg.get("outputs"),
                msg.get("signals"),
                msg.get("health"),
                msg.get("configuration"),
            )
            served += 1
            ch.send({"type": "commands", "t": loop.system.t,
                     "commands": [c.to_dict() for c in commands]})
    finally:
        ch.close()
