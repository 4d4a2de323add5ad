"""Small numpy helpers for the viewer: a GLB writer for a triangle mesh with per-vertex colours,
grid normals, a colour map and a colour-bar image. No viser import (testable on its own).

Why a hand-written GLB: viser's ``add_mesh_simple`` takes one colour per mesh; per-vertex colours
(strain and pressure maps) need a glTF asset. trimesh can export one, but it is several times
slower and writes single-sided materials (the cloth vanishes when seen from behind). The writer
below emits exactly one mesh primitive (POSITION, NORMAL, COLOR_0, uint32 indices) with a
double-sided, non-metallic material; building one for a 201 x 201 grid takes a few milliseconds.

glTF stores vertex colours as *linear* RGB; colour maps are defined in sRGB, so
:func:`srgb_to_linear` converts them first (otherwise the map looks washed out).
"""

from __future__ import annotations

import json
import math
import struct

import numpy as np

_GLB_MAGIC = 0x46546C67  # "glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """sRGB components in [0, 1] to linear RGB (IEC 61966-2-1)."""
    c = np.asarray(c, dtype=np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _viridis_lut(n: int = 256) -> np.ndarray:
    try:
        from matplotlib import colormaps

        return np.asarray(colormaps["viridis"](np.linspace(0.0, 1.0, n))[:, :3], dtype=np.float32)
    except Exception:  # matplotlib missing: a blue -> green -> yellow ramp close to viridis
        t = np.linspace(0.0, 1.0, n)[:, None]
        stops = np.array([[0.267, 0.005, 0.329], [0.128, 0.567, 0.551], [0.993, 0.906, 0.144]])
        lo = np.clip(t * 2, 0, 1) * (stops[1] - stops[0]) + stops[0]
        hi = np.clip(t * 2 - 1, 0, 1) * (stops[2] - stops[1]) + stops[1]
        return np.where(t < 0.5, lo, hi).astype(np.float32)


VIRIDIS = _viridis_lut()
VIRIDIS_LINEAR = srgb_to_linear(VIRIDIS)


def colormap(values: np.ndarray, lo: float, hi: float, linear: bool = True) -> np.ndarray:
    """(N,) values -> (N, 3) float32 colours in [0, 1] (viridis); linear RGB for glTF by default."""
    v = np.asarray(values, dtype=np.float64)
    span = hi - lo
    t = (v - lo) / span if span > 0 else np.zeros_like(v)
    t = np.nan_to_num(t, nan=0.0, posinf=1.0, neginf=0.0)
    idx = np.clip((t * (len(VIRIDIS) - 1)).round().astype(np.int64), 0, len(VIRIDIS) - 1)
    return (VIRIDIS_LINEAR if linear else VIRIDIS)[idx]


def colorbar_image(width: int = 256, height: int = 14) -> np.ndarray:
    """A horizontal viridis gradient (uint8 RGB, height x width), low values on the left."""
    row = (colormap(np.linspace(0.0, 1.0, width), 0.0, 1.0, linear=False) * 255).round().astype(np.uint8)
    return np.repeat(row[None, :, :], height, axis=0)


def nice_ticks(lo: float, hi: float, max_ticks: int = 5) -> list[float]:
    """Tick values for a colour range [lo, hi]: the multiples of a round step (1, 2 or 5 times a
    power of ten) that lie in the range, at most ``max_ticks`` of them (at least two for any
    finite range lo < hi). Empty for a non-finite or empty range."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return []
    span = hi - lo
    mag = 10.0 ** math.floor(math.log10(span / max(max_ticks - 1, 1)))
    for step in (m * mag for m in (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)):  # the finest that fits
        tol = 1e-9 * step
        k0, k1 = math.ceil((lo - tol) / step), math.floor((hi + tol) / step)
        if k1 - k0 + 1 <= max_ticks:
            break
    ticks = [k * step for k in range(k0, k1 + 1)]
    if len(ticks) < 2:  # a step too coarse for the range: its ends
        ticks = [lo, hi]
    # rounding noise (0.30000000000000004) off, and -0 as 0
    digits = max(0, -math.floor(math.log10(step)) + 1)
    return [round(t, digits) + 0.0 for t in ticks]


def tick_label(x: float, step: float) -> str:
    """A tick's text: enough digits to tell ticks ``step`` apart; plain decimals where they take
    at most 8 places and the value is below 10^6, else exponent form."""
    if x == 0:
        return "0"
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    if abs(x) < 1e6 and decimals <= 8 and (abs(x) >= 1e-3 or step >= 1e-4):
        text = f"{x:.{decimals}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    sig = max(1, math.floor(math.log10(abs(x))) - math.floor(math.log10(step) + 1e-9) + 1)
    return f"{x:.{min(sig, 12) - 1}e}"


#: colour-bar layout [pixels]: the gradient's height, the tick marks' length below it and the
#: height of the label row
BAR_HEIGHT = 12
TICK_LENGTH = 5
LABEL_HEIGHT = 14
TICK_RGB = (40, 40, 40)


def tick_x(values, lo: float, hi: float, width: int) -> np.ndarray:
    """Pixel columns of tick values on a bar ``width`` pixels wide showing [lo, hi] (lo at column
    0, hi at column width - 1)."""
    return np.rint((np.asarray(values, float) - lo) / (hi - lo) * (width - 1)).astype(np.int64)


def colorbar_with_ticks(lo: float, hi: float, width: int = 256) -> tuple[np.ndarray, list[float]]:
    """The colour bar of the range [lo, hi] with tick marks and their values: a
    (BAR_HEIGHT + TICK_LENGTH + LABEL_HEIGHT, width, 3) uint8 RGB image on white, the viridis
    gradient on top, a dark mark TICK_LENGTH pixels long under each tick of :func:`nice_ticks`
    (column :func:`tick_x`) and the tick's value centred under it. Returns (image, ticks); no
    ticks (the bare bar) for an empty or non-finite range."""
    img = np.full((BAR_HEIGHT + TICK_LENGTH + LABEL_HEIGHT, width, 3), 255, np.uint8)
    img[:BAR_HEIGHT] = colorbar_image(width, BAR_HEIGHT)
    ticks = nice_ticks(lo, hi)
    if not ticks:
        return img, []
    xs = tick_x(ticks, lo, hi, width)
    for x in xs:
        img[BAR_HEIGHT:BAR_HEIGHT + TICK_LENGTH, x] = TICK_RGB
    try:
        from PIL import Image, ImageDraw, ImageFont
    except ImportError:  # no labels without Pillow (matplotlib brings it)
        return img, ticks
    step = ticks[1] - ticks[0] if len(ticks) > 1 else abs(hi - lo)
    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    try:
        font = ImageFont.load_default(size=11)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        font = ImageFont.load_default()
    top = BAR_HEIGHT + TICK_LENGTH
    for t, x in zip(ticks, xs):
        text = tick_label(t, step)
        w = draw.textlength(text, font=font)
        left = min(max(0.0, x - w / 2), width - w)
        draw.text((left, top), text, fill=TICK_RGB, font=font)
    return np.asarray(im), ticks


def vertex_normals(positions: np.ndarray, topology) -> np.ndarray:
    """Unit vertex normals (N, 3) float32 of a lattice (clothsim.topology.Topology): the central
    differences of :func:`grid_normals` on one full rectangle, else the area-weighted normals of
    the display faces round each node (+z where there are none)."""
    if topology.is_grid:
        return grid_normals(positions, *topology.grid_shape)
    p = np.asarray(positions, dtype=np.float32)
    f = topology.faces
    fn = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
    n = np.zeros_like(p)
    for c in range(3):
        np.add.at(n, f[:, c], fn)
    return _unit_or_z(n)


def _unit_or_z(n: np.ndarray) -> np.ndarray:
    """Rows of n (N, 3) scaled to unit length as float32; zero or non-finite rows become +z."""
    length = np.linalg.norm(n, axis=1)
    bad = ~(length > 0)
    length[bad] = 1.0
    n = n / length[:, None]
    n[bad] = (0.0, 0.0, 1.0)
    return n.astype(np.float32)


def grid_normals(positions: np.ndarray, nx1: int, ny1: int) -> np.ndarray:
    """Unit vertex normals (N, 3) float32 of a structured grid: cross product of the central
    differences along i and j (one-sided at the borders). Cheap and smooth; degenerate spots
    fall back to +z."""
    p = np.asarray(positions, dtype=np.float32).reshape(nx1, ny1, 3)
    if nx1 < 2 or ny1 < 2:
        out = np.zeros((nx1 * ny1, 3), np.float32)
        out[:, 2] = 1.0
        return out
    di = np.empty_like(p)
    dj = np.empty_like(p)
    di[1:-1] = p[2:] - p[:-2]
    di[0] = p[1] - p[0]
    di[-1] = p[-1] - p[-2]
    dj[:, 1:-1] = p[:, 2:] - p[:, :-2]
    dj[:, 0] = p[:, 1] - p[:, 0]
    dj[:, -1] = p[:, -1] - p[:, -2]
    return _unit_or_z(np.cross(di, dj).reshape(-1, 3))


def _pad4(b: bytes, fill: bytes) -> bytes:
    return b + fill * ((4 - len(b) % 4) % 4)


class GlbMeshWriter:
    """Builds GLB files for one triangle mesh whose faces do not change (the index buffer is
    packed once); call :meth:`build` with new positions and colours per frame."""

    def __init__(self, faces: np.ndarray, roughness: float = 0.85):
        self.faces = np.ascontiguousarray(faces, dtype=np.uint32)
        self._index_bytes = self.faces.tobytes()
        self.roughness = float(roughness)

    def build(self, positions: np.ndarray, colors_linear: np.ndarray, normals: np.ndarray | None = None,
              opacity: float = 1.0) -> bytes:
        """positions (N, 3) [m], colors_linear (N, 3) in [0, 1] linear RGB, normals (N, 3) or None;
        opacity < 1 gives a blended (see-through) material."""
        pos = np.ascontiguousarray(positions, dtype=np.float32)
        col = np.ascontiguousarray(colors_linear, dtype=np.float32)
        n = len(pos)
        views = []
        blobs = []
        offset = 0

        def add(data: bytes, target: int) -> int:
            nonlocal offset
            views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(data), "target": target})
            blobs.append(data)
            offset += len(data)  # every block is a multiple of 4 bytes (float32 / uint32)
            return len(views) - 1

        finite = pos[np.isfinite(pos).all(axis=1)]
        pmin = finite.min(axis=0).tolist() if len(finite) else [0.0, 0.0, 0.0]
        pmax = finite.max(axis=0).tolist() if len(finite) else [0.0, 0.0, 0.0]
        accessors = [
            {"bufferView": add(pos.tobytes(), 34962), "componentType": 5126, "count": n, "type": "VEC3",
             "min": pmin, "max": pmax},
            {"bufferView": add(col.tobytes(), 34962), "componentType": 5126, "count": n, "type": "VEC3"},
            {"bufferView": add(self._index_bytes, 34963), "componentType": 5125, "count": int(self.faces.size),
             "type": "SCALAR"},
        ]
        attributes = {"POSITION": 0, "COLOR_0": 1}
        if normals is not None:
            nrm = np.ascontiguousarray(normals, dtype=np.float32)
            accessors.append({"bufferView": add(nrm.tobytes(), 34962), "componentType": 5126, "count": n,
                              "type": "VEC3"})
            attributes["NORMAL"] = 3
        material = {"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, float(opacity)],
                                             "metallicFactor": 0.0, "roughnessFactor": self.roughness},
                    "doubleSided": True}
        if opacity < 1.0:
            material["alphaMode"] = "BLEND"
        gltf = {
            "asset": {"version": "2.0", "generator": "clothsim"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0}],
            "meshes": [{"primitives": [{"attributes": attributes, "indices": 2, "material": 0, "mode": 4}]}],
            "materials": [material],
            "buffers": [{"byteLength": offset}],
            "bufferViews": views,
            "accessors": accessors,
        }
        js = _pad4(json.dumps(gltf, separators=(",", ":")).encode(), b" ")
        binary = b"".join(blobs)
        total = 12 + 8 + len(js) + 8 + len(binary)
        return b"".join([
            struct.pack("<III", _GLB_MAGIC, 2, total),
            struct.pack("<II", len(js), _CHUNK_JSON), js,
            struct.pack("<II", len(binary), _CHUNK_BIN), binary,
        ])


def read_glb_positions(glb: bytes) -> np.ndarray:
    """POSITION of the first primitive of a GLB (float32 (N, 3)); used by tests to check what the
    viewer really sent."""
    magic, _version, _total = struct.unpack_from("<III", glb, 0)
    if magic != _GLB_MAGIC:
        raise ValueError("not a GLB")
    jlen, _ = struct.unpack_from("<II", glb, 12)
    gltf = json.loads(glb[20:20 + jlen])
    blen, _ = struct.unpack_from("<II", glb, 20 + jlen)
    binary = glb[28 + jlen:28 + jlen + blen]
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(binary, dtype=np.float32, count=acc["count"] * 3, offset=start).reshape(-1, 3)
