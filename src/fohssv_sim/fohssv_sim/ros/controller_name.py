"""Who answers the plant: the node publishing ``command`` and its ``controller`` parameter (the
law it runs), asked without blocking, for a bag's run metadata (``fohssv.controller_node``,
``fohssv.controller``; ``fohssv plot`` names the law in its titles). The recorder node and the
plant's in-plant recording both ask through :func:`ask`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from rcl_interfaces.srv import GetParameters
from rclpy.clock import Clock, ClockType
from rclpy.parameter import parameter_value_to_python

from .. import contract
from .matching import UNKNOWN_NODE, node_path

__all__ = ['ask', 'command_topic']

#: Wall seconds between two looks for the publisher and its parameter service.
_POLL = 0.1


def command_topic(node: Any) -> str:
    """The plant's command topic: the one it subscribes to (an external controller) or, with
    a hosted controller, the one it publishes on."""
    for attr in ('command_sub', 'command_pub'):
        endpoint = getattr(node, attr, None)
        if endpoint is not None:
            return endpoint.topic_name
    return node.resolve_topic_name(contract.COMMAND.name)


def ask(node: Any, topic: str, done: Callable[[dict[str, Any]], None],
        timeout: float) -> Any:
    """Ask for the node publishing ``topic`` and its ``controller`` parameter, a look every
    0.1 s on the steady clock of ``node``'s executor, and call ``done`` once with the metadata
    found: ``{}`` when no publisher with a known name appeared within ``timeout`` s (DDS
    discovers an endpoint before its node's name: ``_NODE_NAME_UNKNOWN_`` under load, so the
    name is looked up again until it is known); the node's path alone when its parameter
    service did not answer in time or it has no text ``controller`` parameter; both otherwise.
    Returns the timer (``cancel()`` gives up without a call)."""
    deadline = time.monotonic() + timeout
    asking: dict[str, Any] = {}

    def on_reply(future: Any) -> None:
        result = future.result()
        values = ([parameter_value_to_python(v) for v in result.values]
                  if result is not None else [])
        done({'fohssv.controller_node': asking['node'], **(
            {'fohssv.controller': values[0]} if values and isinstance(values[0], str)
            else {})})

    def look() -> None:
        late = time.monotonic() > deadline
        if 'client' not in asking:
            named = [i for i in node.get_publishers_info_by_topic(topic)
                     if i.node_name != UNKNOWN_NODE]
            if not named:
                if late:
                    timer.cancel()
                    done({})
                return
            asking['node'] = node_path(named[0])
            asking['client'] = node.create_client(GetParameters,
                                                  f"{asking['node']}/get_parameters")
        client = asking['client']
        if client.service_is_ready():
            timer.cancel()
            client.call_async(GetParameters.Request(names=['controller'])
                              ).add_done_callback(on_reply)
        elif late:
            timer.cancel()
            done({'fohssv.controller_node': asking['node']})

    timer = node.create_timer(_POLL, look, clock=Clock(clock_type=ClockType.STEADY_TIME))
    return timer
