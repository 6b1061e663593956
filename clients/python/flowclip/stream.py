"""A session's WebSocket stream (/api/sessions/{id}/stream): decoded messages in, client messages out."""

from __future__ import annotations

import re
import time
from urllib.parse import quote

from websockets.sync.client import connect

from .codec import Layer, decode, encode_edit, encode_subscribe, encode_transport
from .operations import route


class Stream:
    """The session's WebSocket (/api/sessions/{id}/stream). recv() returns decoded messages;
    messages skipped by the wait_* helpers are kept in `skipped`."""

    def __init__(self, base_url, sid, token=None, token_as_subprotocol=False, origin=None, timeout=10.0):
        path = route("stream")[1].format(id=quote(sid, safe=""))
        uri = re.sub(r"^http", "ws", base_url.rstrip("/")) + path
        headers, protocols = {}, None
        if token is not None and token_as_subprotocol:
            protocols = [f"flowclip-token.{token}"]
        elif token is not None:
            headers["Authorization"] = f"Bearer {token}"
        self.ws = connect(uri, additional_headers=headers, subprotocols=protocols, origin=origin,
                          max_size=None, open_timeout=timeout, close_timeout=2)
        self.timeout = timeout
        self.skipped = []

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.ws.close()

    @property
    def subprotocol(self):
        return self.ws.subprotocol

    def recv(self, timeout=None) -> dict:
        data = self.ws.recv(timeout=self.timeout if timeout is None else timeout)
        if isinstance(data, str):
            raise ValueError(f"text message from the server: {data[:200]!r}")
        return decode(data)

    def wait(self, kind, where=lambda m: True, timeout=None) -> dict:
        """The next message of type `kind` ("frame", "state", "ack", "error") satisfying `where`."""
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no {kind} message within the timeout")
            m = self.recv(timeout=left)
            if m["type"] == kind and where(m):
                return m
            self.skipped.append(m)

    def wait_frame(self, n, timeout=None) -> dict:
        """The first frame numbered n or later."""
        return self.wait("frame", lambda m: m["frame"] >= n, timeout)

    def frames_until(self, n, timeout=None) -> list:
        """Every frame received until frame n (included); frames may be skipped by the server."""
        frames, deadline = [], time.monotonic() + (self.timeout if timeout is None else timeout)
        while not frames or frames[-1]["frame"] < n:
            frames.append(self.wait("frame", timeout=max(0.01, deadline - time.monotonic())))
        return frames

    def send(self, data: bytes):
        self.ws.send(data)

    def subscribe(self, max_frame_rate=0.0, layers=Layer.Instances, request_id=0):
        self.send(encode_subscribe(max_frame_rate, layers, request_id))

    def transport(self, command, steps=None, frame=None, speed=None, request_id=0):
        self.send(encode_transport(command, steps, frame, speed, request_id))

    def edit(self, edit_id, edit: dict):
        self.send(encode_edit(edit_id, edit))
