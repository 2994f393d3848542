"""The viewer's front door: the WebSocket endpoint Foxglove clients connect to, in front of the
Foxglove SDK's server. Pure: no rclpy (tested alone with a WebSocket client).

The SDK's server speaks the Foxglove WebSocket protocol v1 under the subprotocol name
``foxglove.sdk.v1`` only and refuses a client that offers the protocol's published name
``foxglove.websocket.v1`` (Lichtblick, older Foxglove apps, the npm ``@foxglove/ws-protocol``
client); it accepts any ``Origin`` and any number of connections. The gate, a ``websockets``
server on the viewer's address and port, decides each handshake and relays every accepted
connection frame by frame to the SDK's server on a loopback port of its own (the wire protocol
is the same under both names):

* subprotocol: ``foxglove.sdk.v1`` or ``foxglove.websocket.v1`` (:data:`SUBPROTOCOLS`; the
  client gets the one it offered);
* ``Origin`` (what a browser sends: a web page on this machine could otherwise read the live
  run): none (native clients, Python, the desktop apps), the Foxglove and Lichtblick web apps
  and pages served from this machine (:data:`DEFAULT_ORIGINS`), plus those the viewer's
  ``allowed_origins`` parameter adds;
* at most ``max_clients`` connections at once (a flood of connections is refused, not held).

A refused handshake gets an HTTP error (403 origin, 400 subprotocol, 503 full) with the
reason, and the gate reports it once per reason and peer (the first 100) through
``on_refused`` (the viewer logs it). Hostile frames reach the SDK's server as they came (it
survives malformed ones); a frame larger than 1 MiB from a client closes that connection.
When either side of a relayed connection closes, the gate closes the other, at once even when
frames for a client that fell behind are still on their way; when the viewer stops, a client
that does not answer the close within a second is cut off.
"""

from __future__ import annotations

import asyncio
import contextlib
import re
import threading
from collections.abc import Callable, Sequence
from http import HTTPStatus
from typing import Any

from websockets.asyncio.client import connect
from websockets.asyncio.connection import Connection
from websockets.asyncio.server import ServerConnection, serve
from websockets.exceptions import ConnectionClosed
from websockets.http11 import Request, Response

__all__ = ['Gate', 'SUBPROTOCOLS', 'DEFAULT_ORIGINS', 'origin_allowed', 'SDK_SUBPROTOCOL']

#: The subprotocol the SDK's server speaks.
SDK_SUBPROTOCOL = 'foxglove.sdk.v1'
#: The names of the Foxglove WebSocket protocol v1 a client may offer (current, published).
SUBPROTOCOLS = (SDK_SUBPROTOCOL, 'foxglove.websocket.v1')
#: Origins accepted by default (besides a handshake without Origin): the Foxglove web app,
#: the Lichtblick web app and any page served from this machine (localhost, 127.0.0.1, ::1,
#: any port, http or https).
DEFAULT_ORIGINS = ('https://app.foxglove.dev', 'https://embed.foxglove.dev',
                   'https://app.lichtblick.dev', 'https://lichtblick-suite.github.io')
#: Seconds the clients have to answer the gate's close when it stops, before their connections
#: are cut: a client that stopped reading never answers (its close waits for buffer space).
_CLOSE_GRACE = 1.0
#: Refusal lines logged at most (distinct reason and peer); the count goes on (a flood of
#: handshakes with made-up origins neither fills the log nor the memory).
_MAX_SAID = 100
_LOCAL = re.compile(r'https?://(localhost|127(\.\d{1,3}){3}|\[::1\])(:\d{1,5})?')


def origin_allowed(origin: str | None, extra: Sequence[str] = ()) -> bool:
    """True for no Origin, a local page, :data:`DEFAULT_ORIGINS` and ``extra`` (exact,
    case-insensitive; ``*`` in ``extra`` allows every origin)."""
    if origin is None:
        return True
    o = origin.strip().lower().rstrip('/')
    allowed = {x.lower().rstrip('/') for x in (*DEFAULT_ORIGINS, *extra)}
    return '*' in allowed or o in allowed or bool(_LOCAL.fullmatch(o))


async def _forward(src: Connection, dst: Connection) -> None:
    """Relay ``src``'s frames to ``dst`` until ``src`` closes, then close ``dst``. Once ``dst``
    is gone ``src`` is still read to its end, its frames dropped: websockets stops reading a
    socket while 16 received frames wait unread, so a side left unread with frames queued
    (the SDK's, when its client was behind the views) never sees the close frame that ends
    it, and closing it waited websockets' close_timeout (10 s)."""
    try:
        async for frame in src:
            with contextlib.suppress(ConnectionClosed):
                await dst.send(frame)
    finally:
        await dst.close()


class Gate:
    """The gate on ``host:port`` in front of the SDK's server on ``127.0.0.1:upstream_port``;
    it runs in a thread of its own (an asyncio loop) until :meth:`stop`.

    Args:
        on_refused: called with one line per refused handshake (first of each reason and
            peer address; the count of all is :attr:`refused`).

    Raises:
        OSError: the gate cannot bind ``host:port`` (address in use, unknown host).
    """

    def __init__(self, host: str, port: int, upstream_port: int, *, max_clients: int = 16,
                 allowed_origins: Sequence[str] = (),
                 on_refused: Callable[[str], None] | None = None) -> None:
        self._upstream = f'ws://127.0.0.1:{upstream_port}'
        self.max_clients = max_clients
        self.allowed_origins = tuple(allowed_origins)
        self._on_refused = on_refused or (lambda line: None)
        self._said: set[tuple[str, str]] = set()
        self._relayed: set[ServerConnection] = set()
        self.refused = 0
        self._loop = asyncio.new_event_loop()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(host, port), daemon=True,
                                        name='foxglove-gate')
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            raise OSError(f'cannot serve Foxglove on {host}:{port}: {self._error}') from None

    @property
    def port(self) -> int:
        return self._port

    @property
    def clients(self) -> int:
        """The clients connected now."""
        return len(self._relayed)

    def _run(self, host: str, port: int) -> None:
        async def start() -> Any:
            return await serve(self._relay, host, port, process_request=self._check,
                               select_subprotocol=lambda _, offered: next(
                                   (p for p in offered if p in SUBPROTOCOLS), None),
                               max_size=2 ** 20, compression=None)

        asyncio.set_event_loop(self._loop)
        try:
            self._server = self._loop.run_until_complete(start())
            self._port = self._server.sockets[0].getsockname()[1]
        except (OSError, ValueError) as exc:
            self._error = exc
            return
        finally:
            self._ready.set()
        self._loop.run_forever()

    def _refuse(self, conn: ServerConnection, status: HTTPStatus, reason: str) -> Response:
        self.refused += 1
        peer = conn.remote_address[0] if conn.remote_address else '?'
        if (reason, peer) not in self._said and len(self._said) < _MAX_SAID:
            self._said.add((reason, peer))
            self._on_refused(f'refused a Foxglove client from {peer}: {reason} (HTTP '
                             f'{status.value}; {self.refused} refused so far)')
        return conn.respond(status, reason + '\n')

    def _check(self, conn: ServerConnection, request: Request) -> Response | None:
        """The handshake's verdict: None accepts it, a Response refuses it."""
        origin = request.headers.get('Origin')
        if not origin_allowed(origin, self.allowed_origins):
            return self._refuse(conn, HTTPStatus.FORBIDDEN, f'Origin {origin!r} is not '
                                'allowed (the viewer parameter allowed_origins adds origins)')
        offered = [p.strip() for h in request.headers.get_all('Sec-WebSocket-Protocol')
                   for p in h.split(',')]
        if not any(p in SUBPROTOCOLS for p in offered):
            return self._refuse(conn, HTTPStatus.BAD_REQUEST, f'subprotocols {offered} offer '
                                f"neither of {', '.join(SUBPROTOCOLS)}")
        if self.clients >= self.max_clients:
            return self._refuse(conn, HTTPStatus.SERVICE_UNAVAILABLE, f'{self.clients} '
                                'clients are connected, the most the viewer serves '
                                '(parameter max_clients)')
        return None

    async def _relay(self, client: ServerConnection) -> None:
        """One client's connection: relayed both ways until either side closes; then the
        other side is closed too."""
        self._relayed.add(client)
        try:
            async with connect(self._upstream, subprotocols=[SDK_SUBPROTOCOL],
                               max_size=None, compression=None) as upstream:
                await asyncio.gather(_forward(client, upstream), _forward(upstream, client),
                                     return_exceptions=True)
        except (OSError, ConnectionClosed):
            pass
        finally:
            self._relayed.discard(client)

    def stop(self) -> None:
        """Close the gate and every relayed connection (a client that does not answer the
        close within :data:`_CLOSE_GRACE` s is cut off)."""
        async def close() -> None:
            self._server.close()
            try:
                await asyncio.wait_for(self._server.wait_closed(), _CLOSE_GRACE)
            except TimeoutError:
                for client in list(self._relayed):
                    client.transport.abort()
                await self._server.wait_closed()

        if self._error is None and self._loop.is_running():
            asyncio.run_coroutine_threadsafe(close(), self._loop).result(timeout=10)
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout=10)
