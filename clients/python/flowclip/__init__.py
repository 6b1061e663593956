"""Python client of `flowclip serve`, the FlowClip liquid server.

Headless use, e.g. simulate the drop scene for a second and export it::

    from flowclip import FlowClipServer

    with FlowClipServer(templates="templates", scenes="scenes") as server:
        api = server.client()
        sid = api.create_session("drop2d")["id"]
        with server.stream(sid) as stream:
            api.step(sid, 60)
            frame = stream.wait_frame(60)          # decoded: numpy positions, kinds, instances
            print(frame["frame"], frame["positions"].shape, frame["stats"]["temporary_particles"])
        print(api.export(sid, "drop"))             # EXPORTS_DIR/drop.h5 (+ .xdmf)

Modules:
  server      FlowClipServer starts `flowclip serve --port 0 ...` ($FLOWCLIP_BIN or
              `flowclip` on PATH) and stops it with SIGINT
  client      Client, one method per REST operation; errors raise ApiError
  stream      Stream, the WebSocket: decoded messages, Subscribe, Transport and Edit sent
  codec       the flatbuffers messages (flowclip.wire, generated) to dicts / numpy and back
  operations  the packaged openapi.yaml: OPERATIONS (operationId -> method, path)
"""

from .client import ApiError, Client
from .codec import (decode, encode_edit, encode_subscribe, encode_transport, finish_envelope,
                    rest_world_matrix)
from .operations import OPENAPI_SPEC, OPERATIONS, VERSION, load_operations
from .server import FlowClipServer, default_binary
from .stream import Stream

__version__ = VERSION  # the version of the packaged openapi.yaml: the server release it speaks to

__all__ = [
    "ApiError", "Client", "FlowClipServer", "Stream",
    "OPENAPI_SPEC", "OPERATIONS", "load_operations", "default_binary",
    "decode", "encode_edit", "encode_subscribe", "encode_transport", "finish_envelope", "rest_world_matrix",
    "__version__",
]
