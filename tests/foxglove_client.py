"""A Foxglove WebSocket client for the tests: what the Foxglove app does with the viewer, in
Python (the ``websockets`` package; no part of the SDK).

It opens the connection with the subprotocol the SDK's server speaks, ``foxglove.sdk.v1``
(the Foxglove WebSocket protocol v1: JSON text frames with an ``op``; binary frames with a
1-byte opcode), reads ``serverInfo`` and ``advertise``, subscribes to channels by topic, and
decodes what arrives: Message Data frames (opcode 1: uint32 subscription id, uint64 log time,
payload) with the channel's advertised schema (``json``: JSON; ``protobuf``: the
FileDescriptorSet the server advertised, decoded with ``google.protobuf``) and Time frames
(opcode 2: uint64 ns).
"""

from __future__ import annotations

import base64
import json
import struct
import time
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any

from google.protobuf import descriptor_pb2, descriptor_pool, json_format, message_factory
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SUBPROTOCOL = 'foxglove.sdk.v1'
_MESSAGE_DATA, _TIME = 1, 2


@dataclass
class Received:
    """One decoded message: its channel's topic and schema, log time (ns), the decoded
    message (a protobuf message or a JSON value), a plain dict of it and when it arrived
    (``time.monotonic()``)."""

    topic: str
    schema_name: str
    log_time: int
    message: Any
    fields: Any
    arrived: float


def _protobuf_class(channel: dict) -> Any:
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel['schema']))
    pool = descriptor_pool.DescriptorPool()
    for f in files.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel['schemaName']))


class FoxgloveClient:
    """A connected client. ``texts`` holds every JSON message from the server in order,
    ``received`` the decoded data messages, ``times`` the Time broadcasts."""

    def __init__(self, url: str, timeout: float = 10.0) -> None:
        self._stack = ExitStack()
        # max_queue=None: frames are read as they arrive, as the app reads them (a websockets
        # client holding 16 unread frames stops reading, and its close then waits 10 s for a
        # close frame it no longer reads)
        self.ws = self._stack.enter_context(connect(url, subprotocols=[SUBPROTOCOL],
                                                    open_timeout=timeout, compression=None,
                                                    max_queue=None))
        self.channels: dict[int, dict] = {}
        self.texts: list[dict] = []
        self.received: list[Received] = []
        self.times: list[int] = []
        self._subscriptions: dict[int, dict] = {}
        self._classes: dict[int, Any] = {}
        self._next_id = 1
        self.closed = False

    @property
    def subprotocol(self) -> str | None:
        return self.ws.subprotocol

    def poll(self, timeout: float) -> bool:
        """Take one frame within ``timeout`` s; False when none came (or the server closed
        the connection: :attr:`closed`)."""
        if self.closed:
            return False
        try:
            frame = self.ws.recv(timeout=timeout)
        except TimeoutError:
            return False
        except ConnectionClosed:
            self.closed = True                  # the server stopped
            return False
        if isinstance(frame, str):
            msg = json.loads(frame)
            self.texts.append(msg)
            if msg.get('op') == 'advertise':
                for c in msg['channels']:
                    self.channels[c['id']] = c
            elif msg.get('op') == 'unadvertise':
                for cid in msg['channelIds']:
                    self.channels.pop(cid, None)
            return True
        op = frame[0]
        if op == _TIME:
            self.times.append(struct.unpack_from('<Q', frame, 1)[0])
        elif op == _MESSAGE_DATA:
            sub, log_time = struct.unpack_from('<IQ', frame, 1)
            self.received.append(self._decode(self._subscriptions[sub], log_time, frame[13:]))
        return True

    def _decode(self, channel: dict, log_time: int, payload: bytes) -> Received:
        if channel['encoding'] == 'json':
            value = json.loads(payload)
            return Received(channel['topic'], channel['schemaName'], log_time, value, value,
                            time.monotonic())
        assert channel['encoding'] == 'protobuf', channel
        cls = self._classes.setdefault(channel['id'], _protobuf_class(channel))
        msg = cls.FromString(payload)
        fields = json_format.MessageToDict(msg, preserving_proto_field_name=True,
                                           always_print_fields_with_no_presence=True)
        return Received(channel['topic'], channel['schemaName'], log_time, msg, fields,
                        time.monotonic())

    def drain(self, timeout: float) -> None:
        """Take a frame within ``timeout`` s and then whatever else has arrived."""
        if self.closed:
            time.sleep(min(timeout, 0.05))
        elif self.poll(timeout):
            for _ in range(1000):
                if not self.poll(0):
                    break

    def wait(self, predicate, timeout: float, what: str) -> None:
        """Take frames until ``predicate()`` holds; AssertionError after ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while not predicate():
            left = deadline - time.monotonic()
            if left <= 0:
                raise AssertionError(f'timed out after {timeout} s waiting for {what}')
            self.drain(min(left, 0.2))

    def by_topic(self) -> dict[str, dict]:
        return {c['topic']: c for c in self.channels.values()}

    def subscribe(self, topics) -> None:
        """Subscribe to the advertised channels of ``topics``."""
        channels = self.by_topic()
        subs = []
        for topic in topics:
            channel = channels[topic]
            self._subscriptions[self._next_id] = channel
            subs.append({'id': self._next_id, 'channelId': channel['id']})
            self._next_id += 1
        self.ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))

    def messages(self, topic: str) -> list[Received]:
        return [r for r in self.received if r.topic == topic]

    def close(self) -> None:
        self._stack.close()
