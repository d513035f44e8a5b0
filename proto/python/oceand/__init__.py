"""oceand - Python client of the oceand ocean daemon (protocol v1, proto/PROTOCOL.md).

    from oceand import Client
    with Client("ws://127.0.0.1:8080") as sea:
        sea.subscribe(fields=["height", "dx", "dz"], cascades="all")
        s = sea.surface()                    # one frame of every cascade
        h = s.grid("height", 256)            # the summed sea on a grid of your choosing
        print(sea.query([[10, 20]])["points"][0]["height"])
        boat = sea.launch("boat", 10, -20, heading=90)["body"]   # a floating body (§7.6)
        sea.steer(boat, throttle=0.5, rudder=-0.2)
        seq, bodies = sea.bodies_now()       # every body's state in the newest frame

Modules: frames (the binary frame decoder), surface (cascades summed and
interpolated), client (AsyncClient, Client).
"""
from .frames import (FIELDS, SUBPROTOCOL, VERSION, Assembler, Body, DecoderState, Frame, FrameJoiner, ProtocolError,
                     Tile, decode_bodies, decode_frame)
from .surface import Surface
from .client import AsyncClient, Client, ServerError

__version__ = "0.1.0"
__all__ = ["FIELDS", "SUBPROTOCOL", "VERSION", "Assembler", "Body", "DecoderState", "Frame", "FrameJoiner", "ProtocolError",
           "Tile", "decode_bodies", "decode_frame", "Surface", "AsyncClient", "Client", "ServerError"]
