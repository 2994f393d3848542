"""Options of the Foxglove viewer node: one table and one validated options class.

Pure (no rclpy, no Foxglove SDK). :data:`VIEWER_PARAMETERS` is declared as ROS parameters by
:func:`fohssv_sim.ros.ros_params.declare` and documented in ``docs/ros.md`` from the same rows
(like the recorder's and the player's, :mod:`.bag_options`); :class:`ViewerOptions` validates
the values by the rows and refuses a ``host`` that is no address or host name in the same
words. Every row is read-only: a running viewer keeps its socket.

The viewer binds to the loopback interface by default (``host`` 127.0.0.1): only programs on
this machine can connect. Another address (``0.0.0.0``: every interface) serves the run to
anyone who can reach the machine, without authentication; the node warns when it does.
"""

from __future__ import annotations

import ipaddress
import re

from ..params import ParameterSpec
from .options import TableOptions, TextSpec

__all__ = ['VIEWER_PARAMETERS', 'ViewerOptions', 'DEFAULT_PORT', 'is_loopback']

#: The port Foxglove's *Open connection* dialog proposes (ws://localhost:8765).
DEFAULT_PORT = 8765

_HOST_NAME = re.compile(r'[A-Za-z0-9]([A-Za-z0-9.-]*[A-Za-z0-9])?')
_ORIGIN = re.compile(r'[A-Za-z][A-Za-z0-9+.-]*://[^/\s,]+')

_P = ParameterSpec

#: The viewer's parameters.
VIEWER_PARAMETERS: tuple[ParameterSpec, ...] = (
    TextSpec('host', '-', '127.0.0.1', '-', 'address the Foxglove WebSocket server binds to; '
             'the default, loopback, serves this machine only (0.0.0.0 = every interface, '
             'no authentication: the node warns)', allowed='an IP address or host name'),
    _P('port', '-', DEFAULT_PORT, '-', 'TCP port of the Foxglove WebSocket server '
       '(ws://host:port); 0 = a free port chosen by the system (the node logs it)',
       low=0.0, low_open=False, high=65535.0, high_open=False),
    _P('rate', '-', 30.0, 'Hz', 'most views forwarded per wall-clock second: at each tick the '
       'newest complete view (pose, twist, planing_wrench, both markers of one t), if new',
       low=0.0, high=1000.0, high_open=False),
    _P('max_clients', '-', 16, '-', 'most Foxglove clients connected at once; one more is '
       'refused (HTTP 503, logged)', low=1.0, low_open=False, high=1000.0, high_open=False),
    TextSpec('allowed_origins', '-', '', '-', 'browser origins accepted besides the default '
             'ones (a client without Origin, https://app.foxglove.dev, the Lichtblick web '
             'app, pages served from localhost); comma-separated, e.g. '
             "'https://viz.example.org'; '*' = any origin (any web page this machine's "
             'browser opens can then watch the run); another origin is refused (HTTP 403, '
             'logged)', allowed="'' or comma-separated origins (scheme://host[:port]) or *"),
)


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and the loopback addresses (127.0.0.0/8, ::1)."""
    if host.lower() == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class ViewerOptions(TableOptions):
    """The viewer's validated options (:data:`VIEWER_PARAMETERS`).

    Raises:
        ParameterError: a value out of range or of the wrong kind; a ``host`` that is neither
            an IP address nor a host name.
    """

    TABLE = VIEWER_PARAMETERS

    def check(self) -> None:
        host = self.host.strip()
        try:
            ipaddress.ip_address(host)
        except ValueError:
            if not _HOST_NAME.fullmatch(host):
                raise self.spec('host').refuse(self.host, 'is not an IP address or host '
                                               'name') from None
        self._set('host', host)
        origins = tuple(o.strip() for o in self.allowed_origins.split(',') if o.strip())
        for origin in origins:
            if origin != '*' and not _ORIGIN.fullmatch(origin):
                raise self.spec('allowed_origins').refuse(
                    self.allowed_origins, f'holds {origin!r}, which is no origin '
                    '(scheme://host[:port], e.g. https://viz.example.org)')
        self._set('allowed_origins', origins)

    @property
    def loopback(self) -> bool:
        """True when only this machine can connect."""
        return is_loopback(self.host)
