"""Mold file readers. Each returns ``(V float64 (V, 3), F int64 (F, 3))`` in file units and raises
:class:`MoldError` naming the file and, where known, the line: trimesh's formats (STL, OBJ, PLY,
OFF, GLB/glTF), the paper's points/triangles text format, legacy ASCII VTK polydata and VRML 2.0
``IndexedFaceSet``."""

from __future__ import annotations

import io
import math
import os
import re
from pathlib import Path

import numpy as np

from ..fileio import check_input_file, read_input_bytes
from ..fileio import excerpt as _excerpt
from .record import MoldError

_PAPER_EXTS = {".txt", ".pts", ".tri"}
_VTK_EXTS = {".vtk"}
_VRML_EXTS = {".wrl", ".vrml"}
_TRIMESH_EXTS = {".stl", ".obj", ".ply", ".off", ".glb", ".gltf"}


# --------------------------------------------------------------------------------------------
# file readers: each returns (V float64 (V,3), F int64 (F,3)) and raises MoldError
# --------------------------------------------------------------------------------------------

#: largest index or count accepted in a mold file (int64 arrays hold them; 2**53 also keeps a
#: float spelling such as ``1e15`` exact)
_MAX_INT = 2**53

#: largest mold file read from disk [bytes]: about 5M triangles as binary STL
MAX_MOLD_FILE_BYTES = 256 * 2**20


def mold_file_status(path: Path) -> os.stat_result:
    """``os.stat`` of a mold file named by the user, refusing what cannot be a mold before
    anything is read (:func:`clothsim.fileio.check_input_file`): a missing file, anything but a
    regular file (a device such as /dev/zero, a pipe, a folder), a symbolic link to a file
    outside the folder the path names, and a file over ``MAX_MOLD_FILE_BYTES``. Raises MoldError
    naming the path."""
    return check_input_file(path, MoldError, limit=MAX_MOLD_FILE_BYTES, what="mold file")


def read_mold_file(path: Path, max_bytes: int | None = None) -> bytes:
    """The bytes of a mold file, after :func:`mold_file_status`'s checks; the descriptor is
    checked again once open (a regular file, not a link) and at most ``max_bytes`` (default
    ``MAX_MOLD_FILE_BYTES``) are read, so a file swapped or growing meanwhile cannot make the
    read unbounded."""
    limit = MAX_MOLD_FILE_BYTES if max_bytes is None else max_bytes
    return read_input_bytes(path, MoldError, limit=limit, what="mold file")


_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?|[-+]?(?:nan|inf|infinity)"


def _float(tok: str, name: str, lineno: int, what: str) -> float:
    try:
        v = float(tok.replace("D", "e").replace("d", "e"))
    except ValueError:
        raise MoldError(f"{name}: line {lineno}: {what}: {_excerpt(tok)} is not a number") from None
    if not math.isfinite(v):
        raise MoldError(f"{name}: line {lineno}: {what}: non-finite coordinate {_excerpt(tok)}")
    return v


def _int(tok: str, name: str, lineno: int, what: str) -> int:
    """An integer token (``12``, or a float spelling of one such as ``12.0``), within
    +-``_MAX_INT`` so that it fits the int64 arrays it goes into."""
    try:
        v = int(tok)
    except ValueError:
        try:
            f = float(tok)
        except ValueError:
            f = math.nan
        if not (math.isfinite(f) and f == int(f)):
            raise MoldError(f"{name}: line {lineno}: {what}: {_excerpt(tok)} is not an "
                            f"integer") from None
        v = int(f)
    if abs(v) > _MAX_INT:
        raise MoldError(f"{name}: line {lineno}: {what}: {_excerpt(tok)} is out of range "
                        f"(at most {_MAX_INT} in magnitude)")
    return v


def _read_paper_text(text: str, name: str):
    """The paper's text format: point lines ``index x y z`` then triangle lines ``n1 n2 n3``.

    Triangles refer to the point indices as written (so 0- and 1-based files, and any other
    numbering, work); '#' starts a comment; commas/semicolons count as blanks; a line holding one
    or two integers only (a count header) is skipped.
    """
    labels, coords, label_lines = [], [], []
    tris, tri_lines = [], []
    in_tris = False
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].replace(",", " ").replace(";", " ").strip()
        if not line:
            continue
        toks = line.split()
        if len(toks) in (1, 2) and all(re.fullmatch(r"[+]?\d+", t) for t in toks):
            continue
        if len(toks) == 4:
            if in_tris:
                raise MoldError(f"{name}: line {lineno}: point line 'index x y z' after the "
                                f"triangle lines")
            labels.append(_int(toks[0], name, lineno, "point index"))
            coords.append([_float(t, name, lineno, "point") for t in toks[1:]])
            label_lines.append(lineno)
        elif len(toks) == 3:
            in_tris = True
            tris.append([_int(t, name, lineno, "triangle") for t in toks])
            tri_lines.append(lineno)
        else:
            raise MoldError(f"{name}: line {lineno}: expected 'index x y z' or 'n1 n2 n3', got "
                            f"{len(toks)} fields: {_excerpt(raw.strip())}")
    if not labels and not tris:
        raise MoldError(f"{name}: empty file (no points, no triangles)")
    if not labels:
        raise MoldError(f"{name}: no point lines 'index x y z'")
    if not tris:
        raise MoldError(f"{name}: no triangles")
    lab = np.asarray(labels, dtype=np.int64)
    order = np.argsort(lab, kind="stable")
    sl = lab[order]
    dup = np.flatnonzero(sl[1:] == sl[:-1])
    if len(dup):
        j = order[dup[0] + 1]
        raise MoldError(f"{name}: line {label_lines[j]}: duplicate point index {labels[j]}")
    T = np.asarray(tris, dtype=np.int64)
    pos = np.searchsorted(sl, T)
    pos_c = np.clip(pos, 0, len(sl) - 1)
    ok = sl[pos_c] == T
    if not ok.all():
        r = int(np.flatnonzero(~ok.all(axis=1))[0])
        bad = int(T[r][~ok[r]][0])
        raise MoldError(f"{name}: line {tri_lines[r]}: triangle index {bad} out of range "
                        f"(points are numbered {int(sl[0])}..{int(sl[-1])})")
    return np.asarray(coords, dtype=np.float64)[order], pos_c


def _read_vtk(data: bytes, name: str):
    """Legacy ASCII VTK, DATASET POLYDATA: POINTS and POLYGONS (fanned) / TRIANGLE_STRIPS."""
    text = data.decode("latin-1")
    lines = text.splitlines()
    if not lines or not lines[0].lstrip().lower().startswith("# vtk"):
        raise MoldError(f"{name}: line 1: not a legacy VTK file (expected '# vtk DataFile')")
    if len(lines) < 3:
        raise MoldError(f"{name}: truncated VTK header")
    fmt = lines[2].strip().upper()
    if fmt == "BINARY":
        raise MoldError(f"{name}: line 3: binary VTK is not supported; save it as ASCII "
                        f"(e.g. ParaView 'File > Save Data', Data Mode ASCII) or as STL/PLY")
    if fmt != "ASCII":
        raise MoldError(f"{name}: line 3: expected ASCII or BINARY, got {_excerpt(lines[2].strip())}")
    toks: list[tuple[str, int]] = []
    for i, ln in enumerate(lines[3:], 4):
        for t in ln.split():
            toks.append((t, i))
    pos = 0

    def take(what):
        nonlocal pos
        if pos >= len(toks):
            raise MoldError(f"{name}: unexpected end of file while reading {what}")
        pos += 1
        return toks[pos - 1]

    V = None
    polys: list[list[int]] = []
    poly_lines: list[int] = []
    dataset_seen = False
    while pos < len(toks):
        kw, ln = take("a keyword")
        K = kw.upper()
        if K == "DATASET":
            typ, ln2 = take("the dataset type")
            if typ.upper() != "POLYDATA":
                raise MoldError(f"{name}: line {ln2}: only 'DATASET POLYDATA' is supported, got "
                                f"{_excerpt(typ)}")
            dataset_seen = True
        elif K == "POINTS":
            n = _int(take("POINTS count")[0], name, ln, "POINTS count")
            take("POINTS data type")
            vals = []
            for _ in range(3 * n):
                t, l3 = take("point coordinates")
                vals.append(_float(t, name, l3, "point"))
            V = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
        elif K in ("POLYGONS", "TRIANGLE_STRIPS", "VERTICES", "LINES"):
            n = _int(take(f"{K} count")[0], name, ln, f"{K} count")
            size = _int(take(f"{K} size")[0], name, ln, f"{K} size")
            if pos < len(toks) and toks[pos][0].upper() == "OFFSETS":  # VTK >= 5.1 layout
                take("OFFSETS")
                take("OFFSETS type")
                offs = [_int(take("offsets")[0], name, ln, "offset") for _ in range(n)]
                t, l4 = take("CONNECTIVITY")
                if t.upper() != "CONNECTIVITY":
                    raise MoldError(f"{name}: line {l4}: expected CONNECTIVITY, got {_excerpt(t)}")
                take("CONNECTIVITY type")
                conn, conn_lines = [], []
                for _ in range(size):
                    t, l5 = take("connectivity")
                    conn.append(_int(t, name, l5, "connectivity"))
                    conn_lines.append(l5)
                cells = [(conn[offs[i]:offs[i + 1]], conn_lines[offs[i]] if offs[i] < size else ln)
                         for i in range(n - 1)]
            else:
                cells = []
                for _ in range(n):
                    t, l4 = take(f"{K} cells")
                    k = _int(t, name, l4, f"{K} cell size")
                    ids = [_int(take(f"{K} cells")[0], name, l4, f"{K} cell") for _ in range(k)]
                    cells.append((ids, l4))
            if K == "POLYGONS":
                for ids, l4 in cells:
                    for j in range(1, len(ids) - 1):
                        polys.append([ids[0], ids[j], ids[j + 1]])
                        poly_lines.append(l4)
            elif K == "TRIANGLE_STRIPS":
                for ids, l4 in cells:
                    for j in range(len(ids) - 2):
                        tri = [ids[j], ids[j + 1], ids[j + 2]]
                        if j % 2:
                            tri = [tri[1], tri[0], tri[2]]
                        polys.append(tri)
                        poly_lines.append(l4)
        elif K in ("POINT_DATA", "CELL_DATA", "FIELD", "METADATA"):
            break
        else:
            raise MoldError(f"{name}: line {ln}: unexpected keyword {_excerpt(kw)}")
    if not dataset_seen:
        raise MoldError(f"{name}: no 'DATASET POLYDATA' section")
    if V is None or len(V) == 0:
        raise MoldError(f"{name}: no POINTS")
    if not polys:
        raise MoldError(f"{name}: no triangles (no POLYGONS or TRIANGLE_STRIPS cells)")
    F = np.asarray(polys, dtype=np.int64)
    bad = (F < 0).any(1) | (F >= len(V)).any(1)
    if bad.any():
        r = int(np.flatnonzero(bad)[0])
        raise MoldError(f"{name}: line {poly_lines[r]}: polygon index out of range "
                        f"{F[r].tolist()} (there are {len(V)} points)")
    return V, F


def _match_bracket(text: str, start: int, open_ch: str, close_ch: str) -> int:
    depth = 0
    for i in range(start, len(text)):
        c = text[i]
        if c == open_ch:
            depth += 1
        elif c == close_ch:
            depth -= 1
            if depth == 0:
                return i
    return -1


def _read_vrml(data: bytes, name: str):
    """VRML 2.0: every IndexedFaceSet with ``coord Coordinate { point [...] }`` and
    ``coordIndex [...]`` (polygons fanned); Transform nodes are not applied."""
    text = data.decode("utf-8", errors="replace")
    head = text.lstrip()[:20]
    if not head.startswith("#VRML"):
        raise MoldError(f"{name}: line 1: not a VRML file (expected '#VRML V2.0 utf8')")
    if not head.startswith("#VRML V2.0"):
        raise MoldError(f"{name}: line 1: only VRML 2.0 is supported, got {_excerpt(head.splitlines()[0])}")
    # blank comments but keep offsets (so line numbers stay right)
    text = re.sub(r"#[^\n]*", lambda m: " " * len(m.group(0)), text)

    def line_of(off: int) -> int:
        return text.count("\n", 0, off) + 1

    Vs, Fs, nv = [], [], 0
    for m in re.finditer(r"\bIndexedFaceSet\b", text):
        b0 = text.find("{", m.end())
        b1 = _match_bracket(text, b0, "{", "}") if b0 >= 0 else -1
        if b1 < 0:
            raise MoldError(f"{name}: line {line_of(m.start())}: unterminated IndexedFaceSet")
        block_start = b0
        block = text[b0:b1]
        pm = re.search(r"\bcoord\s+(?:DEF\s+\S+\s+)?Coordinate\s*\{\s*point\s*\[", block)
        im = re.search(r"\bcoordIndex\s*\[", block)
        if pm is None or im is None:
            raise MoldError(f"{name}: line {line_of(m.start())}: IndexedFaceSet without "
                            f"'coord Coordinate {{ point [...] }}' and 'coordIndex [...]' "
                            f"(USE references are not supported)")
        p_end = block.find("]", pm.end())
        i_end = block.find("]", im.end())
        if p_end < 0 or i_end < 0:
            raise MoldError(f"{name}: line {line_of(m.start())}: unterminated '[' list")
        vals = []
        for tm in re.finditer(r"[^\s,]+", block[pm.end():p_end]):
            vals.append(_float(tm.group(0), name, line_of(block_start + pm.end() + tm.start()),
                               "point"))
        if len(vals) % 3:
            raise MoldError(f"{name}: line {line_of(block_start + pm.end())}: point list length "
                            f"{len(vals)} is not a multiple of 3")
        V = np.asarray(vals, dtype=np.float64).reshape(-1, 3)
        poly: list[int] = []
        poly_line = 0
        tris, lines_ = [], []
        toks = list(re.finditer(r"[^\s,]+", block[im.end():i_end])) + [None]
        for tm in toks:
            if tm is None:
                k = -1
            else:
                ln = line_of(block_start + im.end() + tm.start())
                k = _int(tm.group(0), name, ln, "coordIndex")
                if k >= 0 and not poly:
                    poly_line = ln
            if k < 0:
                for j in range(1, len(poly) - 1):
                    tris.append([poly[0], poly[j], poly[j + 1]])
                    lines_.append(poly_line)
                poly = []
            else:
                if k >= len(V):
                    raise MoldError(f"{name}: line {ln}: coordIndex {k} out of range "
                                    f"(there are {len(V)} points)")
                poly.append(k)
        if tris:
            Vs.append(V)
            Fs.append(np.asarray(tris, dtype=np.int64) + nv)
            nv += len(V)
    if not Fs:
        raise MoldError(f"{name}: no triangles (no IndexedFaceSet with faces)")
    return np.concatenate(Vs), np.concatenate(Fs)


def _read_trimesh(data: bytes, name: str, ext: str):
    import trimesh

    try:
        m = trimesh.load(io.BytesIO(data), file_type=ext.lstrip("."), force="mesh", process=False)
    except Exception as e:  # trimesh raises many kinds of errors on bad input
        raise MoldError(f"{name}: cannot parse as {ext.lstrip('.').upper()}: "
                        f"{type(e).__name__}: {_excerpt(str(e), 80, quote=False)}") from None
    if isinstance(m, (list, tuple)):
        m = trimesh.util.concatenate(list(m))
    if not isinstance(m, trimesh.Trimesh):
        raise MoldError(f"{name}: no triangle mesh found (got {type(m).__name__})")
    V = np.asarray(m.vertices, dtype=np.float64)
    F = np.asarray(m.faces, dtype=np.int64)
    if len(F) == 0:
        raise MoldError(f"{name}: no triangles")
    return V, F


def _sniff(data: bytes) -> str | None:
    head = data[:512].lstrip()
    low = head.lower()
    if low.startswith(b"# vtk"):
        return ".vtk"
    if head.startswith(b"#VRML"):
        return ".wrl"
    if low.startswith(b"solid") or low.startswith(b"ply") or low.startswith(b"off"):
        return {b"s": ".stl", b"p": ".ply", b"o": ".off"}[low[:1]]
    if head.startswith(b"glTF"):
        return ".glb"
    try:
        txt = data[:4096].decode("ascii")
    except UnicodeDecodeError:
        return None
    for raw in txt.splitlines():
        line = raw.split("#", 1)[0].replace(",", " ").strip()
        if not line:
            continue
        toks = line.split()
        if len(toks) in (1, 2, 4) and all(re.fullmatch(_NUM, t, re.I) for t in toks):
            if len(toks) == 4:
                return ".txt"
            continue
        if toks[0] in ("v", "f", "vn", "o", "g", "mtllib", "usemtl"):
            return ".obj"
        return None
    return None


def _read_any(data: bytes, name: str):
    if len(data.strip()) == 0:
        raise MoldError(f"{name}: empty file")
    ext = Path(name).suffix.lower()
    if ext not in _PAPER_EXTS | _VTK_EXTS | _VRML_EXTS | _TRIMESH_EXTS:
        sniffed = _sniff(data)
        if sniffed is None:
            raise MoldError(f"{name}: unknown mold format {_excerpt(ext) if ext else repr('(no extension)')}; supported: "
                            f"STL, OBJ, PLY, OFF, GLB/glTF, the paper's .txt/.pts/.tri, "
                            f"legacy ASCII .vtk, VRML 2.0 .wrl")
        ext = sniffed
    if ext in _PAPER_EXTS:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise MoldError(f"{name}: not a text file (expected the points/triangles text "
                            f"format)") from None
        return _read_paper_text(text, name)
    if ext in _VTK_EXTS:
        return _read_vtk(data, name)
    if ext in _VRML_EXTS:
        return _read_vrml(data, name)
    return _read_trimesh(data, name, ext)
