"""Helpers shared by the viewer's tests (not a test module): a small scene, a free port, waiting
for the update loop, and viser's websocket protocol for raw clients."""

from __future__ import annotations

import socket
import time

SMALL = {
    "name": "small-cap",
    "fabric": {"size": [0.1, 0.1], "divisions": [10, 10],
               "warp": {"strain": [0, 1], "tension": [0, 250]},
               "weft": {"strain": [0, 1], "tension": [0, 250]}},
    "constraints": [{"nodes": "perimeter", "axes": "xyz", "stretch": 1.1}],
    "initial": {"lift": 0.03},
    "mold": {"sphere": {"center": [0.05, 0.05, -0.02], "radius": 0.04}},
    "solver": {"method": "paper", "C": 2.0, "e": 1e-6},
}


def small_scene(**solver):
    from clothsim.config import scene_from_dict

    d = {**SMALL, "solver": {**SMALL["solver"], **solver}}
    return scene_from_dict(d)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def settle(app, t: float = 0.15):
    """Let the update loop run the posted tasks and show the (still) state."""
    app.wait_idle(20)
    time.sleep(t)
    app.wait_idle(20)
    t0 = time.time()
    while app.sim.status != "running" and time.time() - t0 < 10 and (
            app.pushed_iteration != app.sim.state.iteration or app.shown != (app.sim.status, app.sim.version)):
        time.sleep(0.02)


def wait_for(fn, timeout: float = 10.0) -> bool:
    """Poll fn() every 50 ms until it is true or timeout [s] has passed; its last value."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        if fn():
            return True
        time.sleep(0.05)
    return bool(fn())


def protocol() -> str:
    """The websocket subprotocol viser speaks."""
    import viser

    return f"viser-v{viser.__version__}"


def encode(msg) -> bytes:
    """A viser message as a raw client sends it."""
    import msgspec

    return msgspec.msgpack.encode(msg.as_serializable_dict())


#: a 89-byte SVG whose curve reaches 1e20 (issue 28 item 1: it froze the viewer while flattened)
BOMB_SVG = b'<svg xmlns="http://www.w3.org/2000/svg"><path d="M0 0 C1e20 0 1e20 1e20 0 1e20 Z"/></svg>'


def pattern_dxf() -> bytes:
    """A plain DXF in millimetres: FRONT, a 100 x 60 rectangle, and BACK, a trapezoid 100/60 wide,
    60 high (areas 6000 and 4800 mm²)."""
    import io

    import ezdxf

    doc = ezdxf.new("R2000", units=4)
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0), (100, 0), (100, 60), (0, 60)], close=True, dxfattribs={"layer": "FRONT"})
    msp.add_lwpolyline([(150, 0), (250, 0), (230, 60), (170, 60)], close=True, dxfattribs={"layer": "BACK"})
    s = io.StringIO()
    doc.write(s)
    return s.getvalue().encode()
