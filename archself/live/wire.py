"""A plant and its MAPE-K loop in two processes: JSON lines over a local socket.

The plant listens (:class:`PlantLink`), the loop connects (:func:`run_remote`);
each message is one JSON object on one line (UTF-8, at most
:data:`MAX_MESSAGE` bytes; non-finite numbers are ``null``, as JSON has no NaN):

==============  =========  ==========================================================
message         direction  fields
==============  =========  ==========================================================
``hello``       loop →     ``protocol`` (1), ``architecture`` (the file's ``name``),
                           ``token`` (the plant's, :attr:`PlantLink.token`)
``refused``     plant →    ``reason``: the hello was refused (a wrong token); closed
``measurement`` plant →    ``t``, ``outputs``, ``signals``, ``health``, ``configuration``
                           (:meth:`archself.live.MeasuredSystem.update`)
``commands``    loop →     ``t``, ``commands`` (a list of :meth:`Command.to_dict`), the
                           answer to every measurement, usually empty
``end``         plant →    the run is over; the loop returns
==============  =========  ==========================================================

The loop answers every measurement, so a plant that waits for the answer before
its next step (:meth:`PlantLink.send`) acts on a decision at the same step a
simulation would; a plant that does not wait reads the answers later and acts
that much later.

The plant binds to a loopback address only (:class:`PlantLink` refuses any
other; a remote loop reaches it through a tunnel, ``ssh -L``) and serves only a
loop that says hello with its token (a random one, :attr:`PlantLink.token`, that
the plant prints): it accepts every connection that comes, keeps up to
:data:`MAX_PENDING` of them waiting for their hello, refuses those with a wrong
token and closes the others once the loop is in, so an idle or impostor
connection cannot lock the loop out. There is no encryption (loopback only). A
message must arrive whole within the timeout: the time limit is on the message,
not on each read, so a peer trickling bytes cannot hold the other end longer.
"""

from __future__ import annotations

import hmac
import ipaddress
import json
import secrets
import selectors
import socket
import time
from collections.abc import Mapping
from typing import Any

from archself.io.jsondata import jsonable
from archself.live.loop import Command, LiveLoop
from archself.live.system import LiveError

__all__ = [
    "MAX_MESSAGE", "MAX_PENDING", "PROTOCOL", "PlantLink", "measured", "parse_address",
    "run_remote",
]

#: Version of the message set above.
PROTOCOL = 1
#: Longest message accepted (bytes, newline included).
MAX_MESSAGE = 8 * 1024 * 1024
#: Connections a plant keeps waiting for their hello at once (the oldest is dropped).
MAX_PENDING = 256
#: Longest hello accepted (bytes).
MAX_HELLO = 4096


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


def _decode(line: bytes) -> dict[str, Any]:
    """One line → a message (an object with a string ``type``), or a :class:`LiveError`."""
    try:
        msg = json.loads(line.decode("utf-8"))  # UTF-8 only (not guessed from a BOM)
    except (UnicodeDecodeError, ValueError) as exc:  # ValueError: an integer of 5,000 digits
        raise LiveError(f"malformed message: {exc}") from None
    except RecursionError:
        raise LiveError("malformed message: nested too deeply") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise LiveError("malformed message: not an object with a 'type'")
    return msg


class _Channel:
    """One connected socket: send a message, read the next one (bounded in size and time).

    ``timeout_s`` bounds a whole message, from the call of :meth:`read` to its last
    byte, not each read of the socket.
    """

    def __init__(self, sock: socket.socket, timeout_s: float | None, pending: bytes = b"") -> None:
        sock.settimeout(timeout_s)
        self.sock = sock
        self.timeout_s = timeout_s
        self._buf = bytearray(pending)
        self.count = 0  # messages read

    def send(self, msg: Mapping[str, Any]) -> None:
        self.sock.settimeout(self.timeout_s)
        self.sock.sendall(_encode(msg))

    def _line(self) -> bytes | None:
        deadline = None if self.timeout_s is None else time.monotonic() + self.timeout_s
        scanned = 0
        while (i := self._buf.find(b"\n", scanned)) < 0:
            scanned = len(self._buf)
            if scanned > MAX_MESSAGE:
                raise LiveError(f"message longer than {MAX_MESSAGE} bytes")
            left = None if deadline is None else deadline - time.monotonic()
            try:
                if left is not None and left <= 0:
                    raise TimeoutError
                self.sock.settimeout(left)
                data = self.sock.recv(1 << 16)
            except TimeoutError:
                part = f" ({len(self._buf)} bytes of one came)" if self._buf else ""
                whole = "whole " if self._buf else ""
                raise LiveError(f"no {whole}message from the peer for {self.timeout_s:g} s"
                                f"{part}") from None
            except OSError as exc:
                raise LiveError(f"the connection failed: {exc.strerror or exc}") from None
            if not data:
                if self._buf:
                    raise LiveError("the peer closed the connection in the middle of a message")
                return None
            self._buf += data
        if i + 1 > MAX_MESSAGE:
            raise LiveError(f"message longer than {MAX_MESSAGE} bytes")
        line = bytes(self._buf[: i + 1])
        del self._buf[: i + 1]
        return line

    def read(self) -> dict[str, Any] | None:
        """The next message, or None when the peer closed the connection."""
        line = self._line()
        if line is None:
            return None
        self.count += 1
        try:
            return _decode(line)
        except LiveError as exc:
            raise LiveError(f"message {self.count}: {exc}") from None

    def close(self) -> None:
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
    token : str, optional
        The secret a loop must say hello with (default: a random one, 32 hex digits).

    Attributes
    ----------
    port : int
        The port listened on.
    token : str
        The loop's token: print it for ``archself live --token`` (or
        ``ARCHSELF_LIVE_TOKEN``).
    refused : int
        Connections closed without serving them (a wrong token, no hello, too many).

    Examples
    --------
    >>> link = PlantLink(port=0)                         # doctest: +SKIP
    >>> print(link.port, link.token, flush=True)         # doctest: +SKIP
    >>> link.accept()                                    # doctest: +SKIP
    >>> commands = link.send(t, outputs=..., signals=..., health=..., configuration=c)
    ...                                                  # doctest: +SKIP
    >>> link.close()                                     # doctest: +SKIP
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, timeout_s: float = 30.0,
                 token: str | None = None) -> None:
        if not is_loopback(host):
            raise LiveError(f"{host}: the plant listens on a loopback address only")
        if token is not None and (not isinstance(token, str) or not token.strip()):
            raise LiveError("the token must be a non-empty string")
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self._server = socket.socket(family, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind((host, int(port)))
        self._server.listen(MAX_PENDING)
        self._server.setblocking(False)
        self.host = host
        self.port = int(self._server.getsockname()[1])
        self.timeout_s = float(timeout_s)
        self.token = secrets.token_hex(16) if token is None else token
        self.refused = 0
        self._channel: _Channel | None = None
        self.hello: dict[str, Any] | None = None

    def _greeted(self, line: bytes) -> dict[str, Any] | None:
        """The hello on ``line`` if it is one with the right token, else None."""
        try:
            msg = _decode(line)
        except LiveError:
            return None
        token = msg.get("token")
        if msg.get("type") != "hello" or not isinstance(token, str):
            return None
        if not hmac.compare_digest(token.encode("utf-8", "replace"),
                                   self.token.encode("utf-8")):
            return None
        return msg

    def accept(self) -> dict[str, Any]:
        """Wait for the loop to connect and say hello with the token; its ``hello`` message.

        Every connection that comes within ``timeout_s`` is accepted and read at
        once (up to :data:`MAX_PENDING`, each hello at most :data:`MAX_HELLO`
        bytes); the first with a hello carrying :attr:`token` is the loop. One with
        another message or token is answered ``refused`` and closed, and the
        others are closed once the loop is in.

        Raises
        ------
        LiveError
            No loop with the token within ``timeout_s`` (the message says how many
            connections were refused).
        """
        deadline = time.monotonic() + self.timeout_s
        sel = selectors.DefaultSelector()
        sel.register(self._server, selectors.EVENT_READ)
        pending: dict[socket.socket, bytearray] = {}

        def drop(sock: socket.socket, reason: str | None) -> None:
            sel.unregister(sock)
            del pending[sock]
            self.refused += 1
            if reason is not None:
                try:
                    sock.send(_encode({"type": "refused", "reason": reason}))
                except OSError:
                    pass
            sock.close()

        try:
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    was = f" ({self.refused} connections refused)" if self.refused else ""
                    raise LiveError(f"no loop connected with the token within "
                                    f"{self.timeout_s:g} s{was}")
                for key, _ in sel.select(left):
                    if key.fileobj is self._server:
                        try:
                            sock, _ = self._server.accept()
                        except OSError:
                            continue
                        if len(pending) >= MAX_PENDING:
                            drop(next(iter(pending)), None)  # the oldest waiting
                        sock.setblocking(False)
                        pending[sock] = bytearray()
                        sel.register(sock, selectors.EVENT_READ)
                        continue
                    sock = key.fileobj  # type: ignore[assignment]
                    try:
                        data = sock.recv(MAX_HELLO)
                    except BlockingIOError:
                        continue
                    except OSError:
                        data = b""
                    buf = pending[sock]
                    buf += data
                    end = buf.find(b"\n")
                    if end < 0:
                        if not data or len(buf) > MAX_HELLO:
                            drop(sock, None if not data else "hello too long")
                        continue
                    msg = self._greeted(bytes(buf[:end]))
                    if msg is None:
                        drop(sock, "no hello with the plant's token")
                        continue
                    sel.unregister(sock)
                    del pending[sock]
                    sock.setblocking(True)
                    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self._channel = _Channel(sock, self.timeout_s, bytes(buf[end + 1:]))
                    self.hello = msg
                    return msg
        finally:
            for sock in list(pending):
                drop(sock, None)
            sel.close()

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


def run_remote(loop: LiveLoop, host: str, port: int, *, timeout_s: float = 30.0,
               token: str | None = None) -> int:
    """Connect ``loop`` to a plant at ``host:port`` and serve it until it ends the run.

    Every measurement is pushed into the loop (:meth:`LiveLoop.push`) and answered
    with the commands the push gave.

    Parameters
    ----------
    loop : LiveLoop
    host, port : str, int
        The plant's address.
    timeout_s : float
        Longest wait for the connection or for any whole message (a hang guard).
    token : str, optional
        The plant's token (:attr:`PlantLink.token`); without it the plant refuses.

    Returns
    -------
    int
        The number of measurements served.

    Raises
    ------
    LiveError
        The plant cannot be reached, falls silent for ``timeout_s``, closes the
        connection without ``end``, refuses the token, or sends a malformed
        message or a measurement the loop refuses (the message says which one,
        counted from 1, and which field).
    """
    try:
        sock = socket.create_connection((host, int(port)), timeout=timeout_s)
    except OSError as exc:
        raise LiveError(f"cannot connect to the plant at {host}:{port}: {exc}") from None
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    ch = _Channel(sock, timeout_s)
    served = 0
    try:
        ch.send({"type": "hello", "protocol": PROTOCOL, "architecture": loop.arch.name,
                 "token": token})
        while True:
            msg = ch.read()
            if msg is None:
                raise LiveError("the plant closed the connection without ending the run")
            kind = msg["type"]
            if kind == "end":
                return served
            if kind == "refused":
                raise LiveError(f"the plant refused the loop: {msg.get('reason')} "
                                "(pass the token it printed: --token or ARCHSELF_LIVE_TOKEN)")
            if kind != "measurement":
                raise LiveError(f"message {ch.count}: unexpected message {kind!r} from the plant")
            try:
                commands = loop.push(
                    msg.get("t", float("nan")),
                    msg.get("outputs"),
                    msg.get("signals"),
                    msg.get("health"),
                    msg.get("configuration"),
                )
            except LiveError as exc:
                raise LiveError(f"message {ch.count} (measurement {served + 1}): {exc}") from None
            served += 1
            ch.send({"type": "commands", "t": loop.system.t,
                     "commands": [c.to_dict() for c in commands]})
    finally:
        ch.close()
