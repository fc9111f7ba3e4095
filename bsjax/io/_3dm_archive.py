"""A trimmed one-face `ON_Brep` written as an OpenNURBS binary archive of one object, for
`rhino3dm.CommonObject.Decode` (rhino3dm has no API that builds loops and trims).

The archive layout follows OpenNURBS's own writers (facts only, no code): a chunk is a 4-byte
typecode and an 8-byte length (archive version 60) followed by its bytes; a typecode with the
`TCODE_CRC` bit (0x8000) ends with the zlib CRC-32 of the chunk's *direct* bytes (nested chunks,
headers included, are left out: OpenNURBS updates only the innermost chunk's CRC); a typecode with
`TCODE_SHORT` (0x80000000) holds its value in the length field and has no body. An object is
`TCODE_OPENNURBS_CLASS` { `_CLASS_UUID` (the class id), `_CLASS_DATA` (the object's `Write`),
`_CLASS_END` }. `ON_Brep::Write` (chunk version 3.3) writes the arrays `m_C2`, `m_C3`, `m_S`,
`m_V`, `m_E`, `m_T`, `m_L`, `m_F` as anonymous chunks, the bounding box, two mesh chunks, the
solid flag and a region-topology chunk. The curves and the surface inside are rhino3dm's own
encodings (`Encode()`), so only the topology records are written here.

Each loop edge of the bsjax polyline is one trim: a degree-1 2-D `ON_NurbsCurve` in the surface's
domain and an edge whose 3-D curve is a degree-1 `ON_NurbsCurve` through the surface evaluated at
`EDGE_POINTS` points along the segment (its tolerance is the largest gap measured between the
surface and that polyline). Segments on the seam of a closed direction pair up as `seam` trims of
one edge, segments on a collapsed side are `singular` trims (no edge).
"""

from __future__ import annotations

import base64
import itertools
import struct
import uuid
import zlib

import numpy as np

from bsjax._optional import require

TCODE_ANONYMOUS = 0x40008000
TCODE_CLASS, TCODE_CLASS_UUID, TCODE_CLASS_DATA, TCODE_CLASS_END = 0x27FFA, 0x2FFFB, 0x2FFFC, 0x80027FFF
BREP_CLASS_UUID = bytes.fromhex("c5dbb56060e6d311bfe40010830122f0")  # ON_Brep's class id (bytes_le)
BOUNDARY, SEAM, SINGULAR = 1, 3, 4  # ON_BrepTrim::TYPE
NOT_ISO, X_ISO, Y_ISO, W_ISO, S_ISO, E_ISO, N_ISO = range(7)  # ON_Surface::ISO
OUTER, INNER = 1, 2  # ON_BrepLoop::TYPE
EDGE_POINTS = 9


class _Chunk:
    """A long chunk being written: direct bytes and nested chunks in order."""

    def __init__(self, typecode: int):
        self.typecode, self.parts = typecode, []

    def raw(self, data: bytes) -> _Chunk:
        self.parts.append((True, data))
        return self

    def ints(self, *values) -> _Chunk:
        return self.raw(struct.pack(f"<{len(values)}i", *values))

    def doubles(self, *values) -> _Chunk:
        return self.raw(struct.pack(f"<{len(values)}d", *(float(x) for x in values)))

    def array(self, values) -> _Chunk:  # ON_SimpleArray<int>: count, items
        return self.ints(len(values), *values)

    def nested(self, data: bytes) -> _Chunk:
        self.parts.append((False, data))
        return self

    def bytes(self) -> bytes:
        body = b"".join(data for _, data in self.parts)
        if self.typecode & 0x8000:
            body += struct.pack("<I", zlib.crc32(b"".join(d for direct, d in self.parts if direct)))
        return struct.pack("<Iq", self.typecode, len(body)) + body


def _object(class_uuid: bytes, data: _Chunk) -> bytes:
    """`WriteObject`'s class chunk: the class id, the object's data, the end mark."""
    end = struct.pack("<Iq", TCODE_CLASS_END, 0)
    return (
        _Chunk(TCODE_CLASS)
        .nested(_Chunk(TCODE_CLASS_UUID).raw(class_uuid).bytes())
        .nested(data.bytes())
        .nested(end)
        .bytes()
    )


def _encoded(geometry) -> bytes:
    """rhino3dm's archive of one object: the object's class chunk as `WriteObject` writes it."""
    return base64.b64decode(geometry.Encode()["data"])


def _curve_array(curves) -> bytes:
    chunk = _Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(len(curves))
    for curve in curves:
        chunk.ints(1).nested(_encoded(curve))
    return chunk.bytes()


def _polyline(points: np.ndarray, dim: int):
    """A degree-1 rhino3dm `NurbsCurve` through `points (k, dim)`, parameter = point index."""
    rhino3dm = require("rhino3dm", "cad", ".3dm files")

    out = rhino3dm.NurbsCurve(dim, False, 2, len(points))
    for i, p in enumerate(points):
        x, y, z = (*p, 0.0)[:3] if dim == 2 else p
        out.Points[i] = rhino3dm.Point4d(float(x), float(y), float(z), 1.0)
    for i in range(len(points)):
        out.Knots[i] = float(i)
    return out


def _iso(a: np.ndarray, b: np.ndarray, domain, tol: float) -> int:
    (u0, u1), (v0, v1) = domain
    if abs(a[0] - b[0]) <= tol:
        return W_ISO if abs(a[0] - u0) <= tol else E_ISO if abs(a[0] - u1) <= tol else X_ISO
    if abs(a[1] - b[1]) <= tol:
        return S_ISO if abs(a[1] - v0) <= tol else N_ISO if abs(a[1] - v1) <= tol else Y_ISO
    return NOT_ISO


def trimmed_brep(srf, loops, outer, reversed_: bool, closed=(False, False), tol: float = 1e-9):
    """A rhino3dm `Brep` of one face of `srf` (a rhino3dm `NurbsSurface`) trimmed by `loops`.

    **Arguments:** `srf`: the surface; `loops`: closed polylines `(k + 1, 2)` in bsjax's [0, 1]²
    (first point repeated), outer loops counter-clockwise and holes clockwise, inside [0, 1]²;
    `outer`: per loop, `True` for an outer loop; `reversed_`: the face's orientation flag;
    `closed`: per direction whether the surface closes there (seam trims); `tol`: in [0, 1]²,
    how close a point must be to a side to lie on it.

    **Returns:** the decoded `rhino3dm.Brep`, or `None` when rhino3dm refuses the archive.
    """
    rhino3dm = require("rhino3dm", "cad", ".3dm files")

    dom = [(srf.Domain(0).T0, srf.Domain(0).T1), (srf.Domain(1).T0, srf.Domain(1).T1)]
    scale = np.array([d[1] - d[0] for d in dom])
    origin = np.array([d[0] for d in dom])

    def point(uv):
        p = srf.PointAt(*(float(x) for x in origin + scale * uv))
        return np.array([p.X, p.Y, p.Z])

    v_points = []  # the distinct 3-D vertex points

    def vertex(uv) -> int:
        p = point(uv)
        for k, q in enumerate(v_points):
            if np.linalg.norm(p - q) <= 1e-9 * max(1.0, float(np.abs(q).max())):
                return k
        v_points.append(p)
        return len(v_points) - 1

    c2, c3, edges, trims, loop_recs = [], [], [], [], []
    seam_edges = {}  # (side, other coordinate span) → edge index, to pair the seam trims
    for li, (loop, is_outer) in enumerate(zip(loops, outer)):
        loop = np.asarray(loop, dtype=np.float64)
        x, y = loop[:-1, 0], loop[:-1, 1]
        area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
        if (area > 0) != bool(is_outer):  # outer loops counter-clockwise, holes clockwise
            loop = loop[::-1]
        ti_list = []
        for a, b in itertools.pairwise(loop):
            if np.allclose(a, b, atol=tol, rtol=0):
                continue
            va, vb = vertex(a), vertex(b)
            ts = np.linspace(0.0, 1.0, EDGE_POINTS)
            uvs = a + ts[:, None] * (b - a)
            pts = np.array([point(uv) for uv in uvs])
            length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
            iso = _iso(a, b, [(0, 1), (0, 1)], tol)
            ti = len(trims)
            c2.append(_polyline(origin + scale * np.stack([a, b]), 2))
            if va == vb and length <= 1e-12 * max(1.0, float(np.abs(pts).max())):
                trims.append(dict(c2=len(c2) - 1, ei=-1, vi=(va, vb), rev=0, type=SINGULAR, iso=iso, li=li))
            else:
                axis = 0 if iso in (W_ISO, E_ISO) else 1 if iso in (S_ISO, N_ISO) else None
                key = None
                if axis is not None and closed[axis]:
                    span = tuple(sorted(np.round((a[1 - axis], b[1 - axis]), 9)))
                    key = (axis, span)
                if key is not None and key in seam_edges:
                    ei = seam_edges.pop(key)
                    edges[ei]["ti"].append(ti)
                    trims[edges[ei]["ti"][0]]["type"] = SEAM
                    trims.append(dict(c2=len(c2) - 1, ei=ei, vi=(va, vb), rev=1, type=SEAM, iso=iso, li=li))
                else:
                    mids = np.array([point(uv) for uv in (uvs[:-1] + uvs[1:]) / 2])
                    gap = float(np.linalg.norm(mids - (pts[:-1] + pts[1:]) / 2, axis=1).max())
                    c3.append(_polyline(pts, 3))
                    ei = len(edges)
                    edges.append(dict(c3=len(c3) - 1, vi=(va, vb), ti=[ti], tol=gap, n=EDGE_POINTS - 1))
                    if key is not None:
                        seam_edges[key] = ei
                    trims.append(
                        dict(c2=len(c2) - 1, ei=ei, vi=(va, vb), rev=0, type=BOUNDARY, iso=iso, li=li)
                    )
            ti_list.append(ti)
        loop_recs.append((ti_list, OUTER if is_outer else INNER))

    vertex_edges = [[] for _ in v_points]
    for ei, e in enumerate(edges):
        for v in dict.fromkeys(e["vi"]):
            vertex_edges[v].append(ei)

    brep = _Chunk(TCODE_CLASS_DATA).raw(b"\x33")
    brep.nested(_curve_array(c2)).nested(_curve_array(c3))
    brep.nested(_Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(1, 1).nested(_encoded(srf)).bytes())
    chunk = _Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(len(v_points))
    for k, (p, ei) in enumerate(zip(v_points, vertex_edges)):
        chunk.ints(k).doubles(*p).array(ei).doubles(0.0)
    brep.nested(chunk.bytes())
    chunk = _Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(len(edges))
    for k, e in enumerate(edges):
        chunk.ints(k, e["c3"], 0).doubles(0, e["n"]).ints(*e["vi"]).array(e["ti"])
        chunk.doubles(e["tol"] * 1.01 + 1e-12, 0, e["n"])
    brep.nested(chunk.bytes())
    chunk = _Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(len(trims))
    for k, t in enumerate(trims):
        chunk.ints(k, t["c2"]).doubles(0, 1).ints(t["ei"], *t["vi"], t["rev"], t["type"], t["iso"], t["li"])
        chunk.doubles(0, 0, 0, 1).raw(bytes(32)).doubles(0, 0)
    brep.nested(chunk.bytes())
    chunk = _Chunk(TCODE_ANONYMOUS).raw(b"\x10").ints(len(loop_recs))
    for k, (ti_list, kind) in enumerate(loop_recs):
        chunk.ints(k).array(ti_list).ints(kind, 0)
    brep.nested(chunk.bytes())
    face = _Chunk(TCODE_ANONYMOUS).raw(b"\x11").ints(1, 0).array(list(range(len(loop_recs))))
    face.ints(0, int(reversed_), 0).raw(uuid.uuid4().bytes_le)
    brep.nested(face.bytes())
    brep.doubles(1, 0, 0, -1, 0, 0)  # an empty box: the reader computes it
    for _ in range(2):  # no render / analysis meshes
        brep.nested(_Chunk(TCODE_ANONYMOUS).raw(b"\x00").bytes())
    brep.ints(0)  # m_is_solid: unknown
    brep.nested(_Chunk(TCODE_ANONYMOUS).ints(1, 1).raw(b"\x00").bytes())  # no region topology
    data = _object(BREP_CLASS_UUID, brep)
    encoded = {"version": 10000, "archive3dm": 60, "opennurbs": -1869833980}
    encoded["data"] = base64.b64encode(data).decode("ascii")
    return rhino3dm.CommonObject.Decode(encoded)
