"""Fused clouds as PLY files.

``write_ply`` writes binary little-endian PLY with one ``vertex`` element and the properties
``x y z`` (float32, metres; ``run`` and ``fuse`` write them in their output frame, ``--world``), ``red green blue`` (uint8), ``weight`` (float32, the
fusion weight of eq. 22) and ``camera`` (int16, source camera index in rig order). Open3D,
trimesh, CloudCompare and MeshLab read it (unknown properties are ignored by viewers).

``read_ply`` reads that format back exactly, and also any vertex PLY (ascii or binary) with at
least x, y, z (an optional ``support`` short, cameras agreeing on the point, is written when the
cloud has one and read when present): missing colours become 0, a missing weight 1.0, a missing camera -1.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError
from fuseflow.io.files import read_bytes, write_bytes_atomic
from fuseflow.types import FusedCloud

__all__ = ["write_ply", "read_ply", "read_ply_columns", "ply_point_count"]

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip

_FIELDS = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
           ("weight", "<f4"), ("camera", "<i2")]  # fmt: skip


def write_ply(path: str | Path, cloud: FusedCloud) -> Path:
    """Write ``cloud`` as binary little-endian PLY (written to a temp file, then renamed)."""
    path = Path(path)
    c = cloud.numpy()
    fields = _FIELDS + ([("support", "<i2")] if c.support is not None else [])
    arr = np.empty(len(c), dtype=fields)
    xyz, rgb = c.xyz, c.rgb
    arr["x"], arr["y"], arr["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    arr["red"], arr["green"], arr["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    arr["weight"] = c.weight
    arr["camera"] = c.camera
    extra = ""
    if c.support is not None:
        arr["support"] = c.support
        extra = "property short support\n"
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment fuseflow fused cloud, metres, output frame (manifest.json world)\n"
        f"element vertex {len(c)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "property float weight\nproperty short camera\n" + extra + "end_header\n"
    )
    return write_bytes_atomic(path, header.encode("ascii"), arr.tobytes())


def _parse_header(path: Path, data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str]]]], int]:
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    nl = data.find(b"\n", end)
    body_start = len(data) if nl < 0 else nl + 1
    lines = data[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements: list[tuple[str, int, list[tuple[str, str]]]] = []
    for ln in lines[1:]:
        parts = ln.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append((parts[1], int(parts[2]), []))
        elif parts[0] == "property":
            if not elements:
                raise FormatError(f"{path}: property before any element")
            if parts[1] == "list":
                elements[-1][2].append((parts[-1], "list"))
            else:
                if parts[1] not in _PLY_TYPES:
                    raise FormatError(f"{path}: unknown PLY property type {parts[1]!r}")
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise FormatError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements, body_start


def ply_point_count(path: str | Path) -> int:
    """Number of points a PLY file declares (its first element), reading only the header
    (FormatError when it is not a vertex PLY)."""
    path = Path(path)
    with open(path, "rb") as f:
        head = f.read(1 << 16)  # a FuseFlow header is a few hundred bytes
    _, elements, _ = _parse_header(path, head)
    if not elements or elements[0][0] != "vertex":
        raise FormatError(f"{path}: expected 'vertex' as the first element")
    return elements[0][1]


def read_ply(path: str | Path) -> FusedCloud:
    """Read a vertex PLY into a FusedCloud (see module docstring for defaults of missing fields)."""
    cols = read_ply_columns(path)
    count = len(cols["x"])
    xyz = np.stack([cols["x"], cols["y"], cols["z"]], axis=1)
    if all(k in cols for k in ("red", "green", "blue")):
        rgb = np.stack([cols["red"], cols["green"], cols["blue"]], axis=1)
    else:
        rgb = np.zeros((count, 3))
    weight = cols.get("weight", np.ones(count))
    camera = cols.get("camera", np.full(count, -1))
    return FusedCloud.from_numpy(xyz, rgb, weight, camera, cols.get("support"))


def read_ply_columns(path: str | Path) -> dict[str, np.ndarray]:
    """The vertex properties of a vertex PLY by name, each (M,) as stored (FormatError when it
    has no x, y, z, is truncated or has list properties)."""
    path = Path(path)
    data = read_bytes(path)
    fmt, elements, start = _parse_header(path, data)
    if not elements or elements[0][0] != "vertex":
        raise FormatError(f"{path}: expected 'vertex' as the first element")
    _, count, props = elements[0]
    if any(t == "list" for _, t in props):
        raise FormatError(f"{path}: list properties in the vertex element are not supported")
    names = [n for n, _ in props]
    for need in ("x", "y", "z"):
        if need not in names:
            raise FormatError(f"{path}: vertex element has no '{need}' property")
    if fmt == "ascii":
        text = data[start:].decode("ascii", errors="replace").split("\n")
        rows = [ln for ln in text if ln.strip()][:count]
        if len(rows) < count:
            raise FormatError(f"{path}: truncated, {len(rows)} of {count} vertices")
        table = np.array([[float(v) for v in r.split()[: len(names)]] for r in rows]).reshape(count, len(names))
        cols = {n: table[:, k] for k, n in enumerate(names)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(n, order + t) for n, t in props])
        need_bytes = dtype.itemsize * count
        if len(data) - start < need_bytes:
            raise FormatError(f"{path}: truncated, {len(data) - start} of {need_bytes} bytes of vertex data")
        arr = np.frombuffer(data, dtype=dtype, count=count, offset=start)
        cols = {n: arr[n] for n in names}
    return cols
