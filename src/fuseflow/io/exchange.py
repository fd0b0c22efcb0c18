"""Clouds and meshes in the formats content tools read: Draco (.drc) and glTF binary (.glb).

- **Draco** (``write_drc`` / ``read_drc``, with ``DracoPy``, a dependency of fuseflow):
  positions quantised on a grid whose step keeps every point within ``error_mm`` (default
  ``DRC_ERROR_MM`` = 1 mm) of where it was: ``quantization_bits`` = the smallest b with
  sqrt(3)/2 * extent / (2^b - 1) <= error_mm (extent = the cloud's largest side; the half-step
  on each axis is the worst case, sqrt(3)/2 of a step in 3D), at least 8, at most 30; colours
  as 8-bit RGB. The point order is kept (``preserve_order``: point k of the file is point k of
  the cloud; Draco's reordering encoder packs ~15 % smaller but took 0.65 CPU s for 100 k
  coloured points and 50 s for 540 k, growing faster than the point count); weight and source
  camera are not stored (PLY keeps them). An empty cloud is a valid zero-point Draco file.
- **GLB point cloud** (``write_glb_points``): one glTF 2.0 mesh primitive in ``POINTS`` mode with
  ``POSITION`` (float32, metres), ``COLOR_0`` (normalised uint8 RGBA, alpha 255) and ``_WEIGHT`` (float32,
  the fusion weight; glTF's application-specific attribute). Three.js, Babylon.js, Blender,
  Unity (glTFast) and trimesh load it. An empty cloud is a GLB with a scene of one node and no
  mesh (glTF forbids zero-length accessors).
- **GLB mesh** (``write_glb_mesh``): ``TRIANGLES`` with ``POSITION``, ``NORMAL`` (when given),
  ``COLOR_0`` and uint32 indices; an empty mesh as for an empty cloud.

Positions are in the output frame, metres, as the PLY files (``--world``, docs/formats.md). glTF's
+y is "up": ``run`` and ``fuse`` put the rotation from the output frame to glTF's axes (z up to
+y up for the floor frame) on the GLB's node (``up``), so glTF viewers and trimesh show the
capture upright while the accessor holds the same numbers as the PLY.
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path

import numpy as np

from fuseflow.errors import FormatError, ValidationError
from fuseflow.io.files import read_bytes, write_bytes_atomic
from fuseflow.types import FusedCloud

__all__ = [
    "CLOUD_FORMATS",
    "DRC_ERROR_MM",
    "draco_bits",
    "write_drc",
    "read_drc",
    "write_glb_points",
    "write_glb_mesh",
    "write_cloud",
    "read_cloud",
    "has_weight",
    "draco_module",
]

CLOUD_FORMATS = ("ply", "drc", "glb", "splat")
"""Per-frame cloud formats; "splat" is a 3D Gaussian splat PLY (``io.splat``)."""
DRC_ERROR_MM = 1.0
"""Default bound on the Draco position error, millimetres."""


def draco_module():
    """The DracoPy module; FormatError with the install line when it is missing."""
    return _need_draco()


def _need_draco():
    try:
        import DracoPy
    except ImportError:
        raise FormatError("Draco output needs DracoPy (a dependency of fuseflow): pip install DracoPy") from None
    return DracoPy


def draco_bits(extent_m: float, error_mm: float = DRC_ERROR_MM) -> int:
    """Quantisation bits that keep a cloud of largest side ``extent_m`` within ``error_mm``."""
    if not (error_mm > 0 and math.isfinite(error_mm)):
        raise ValidationError(f"Draco error bound must be a positive number of millimetres, got {error_mm}")
    steps = math.sqrt(3) / 2 * max(float(extent_m), 1e-6) / (error_mm / 1000.0)
    return int(min(30, max(8, math.ceil(math.log2(steps + 1)))))


def write_drc(path: str | Path, cloud: FusedCloud, error_mm: float = DRC_ERROR_MM) -> Path:
    """Write ``cloud``'s positions and colours as a Draco point cloud (see the module docstring)."""
    dp = _need_draco()
    c = cloud.numpy()
    xyz = c.xyz.astype(np.float32)
    if len(xyz) == 0:
        data = dp.encode(np.zeros((0, 3), np.float32), quantization_range=1.0, quantization_origin=np.zeros(3))
    else:
        lo = xyz.min(axis=0)
        extent = float((xyz.max(axis=0) - lo).max())
        data = dp.encode(
            xyz, quantization_bits=draco_bits(extent, error_mm), colors=np.ascontiguousarray(c.rgb),
            preserve_order=True,
        )  # fmt: skip
    return write_bytes_atomic(Path(path), data)


def read_drc(path: str | Path) -> FusedCloud:
    """A Draco point cloud as a FusedCloud (weight 1.0 and camera -1: Draco does not store them;
    ``has_weight`` tells a reader whether a file keeps the weights)."""
    dp = _need_draco()
    path = Path(path)
    try:
        d = dp.decode(read_bytes(path))
    except Exception as exc:  # DracoPy raises its own kinds for corrupt buffers
        raise FormatError(f"{path}: not a readable Draco file ({exc})") from None
    pts = np.asarray(d.points, np.float32)
    xyz = pts.reshape(-1, 3) if pts.ndim == 2 else np.zeros((0, 3), np.float32)  # a zero-point file
    rgb = np.asarray(d.colors, np.uint8)[:, :3] if d.colors is not None and len(xyz) else np.zeros((len(xyz), 3))
    return FusedCloud.from_numpy(xyz, rgb, np.ones(len(xyz)), np.full(len(xyz), -1))


def _pad(b: bytes, fill: bytes) -> bytes:
    return b + fill * (-len(b) % 4)


def _node(name: str, matrix: np.ndarray | None) -> dict:
    """A glTF node with ``matrix`` (4x4, row-major here; glTF stores it column-major) unless None."""
    node: dict = {"name": name}
    if matrix is not None:
        node["matrix"] = [float(v) for v in np.asarray(matrix, np.float64).T.reshape(-1)]
    return node


def _glb(
    attributes: dict[str, np.ndarray], indices: np.ndarray | None, mode: int, matrix: np.ndarray | None = None
) -> bytes:
    """A GLB of one mesh with one primitive (``mode`` 0 POINTS, 4 TRIANGLES) on a node with
    ``matrix`` (None: none); no mesh when the position array is empty."""
    gltf: dict = {"asset": {"version": "2.0", "generator": "fuseflow"}, "scene": 0, "scenes": [{"nodes": [0]}]}
    n = len(attributes["POSITION"])
    if n == 0:
        gltf["nodes"] = [_node("empty", matrix)]
        return _glb_bytes(gltf, b"")
    blob, views, accessors, prim = b"", [], [], {}
    arrays = list(attributes.items()) + ([("indices", indices)] if indices is not None else [])
    for name, arr in arrays:
        arr = np.ascontiguousarray(arr)
        ctype = {np.dtype(np.float32): 5126, np.dtype(np.uint8): 5121, np.dtype(np.uint32): 5125}[arr.dtype]
        acc = {"bufferView": len(views), "componentType": ctype, "count": int(arr.size if arr.ndim == 1 else len(arr))}
        acc["type"] = "SCALAR" if arr.ndim == 1 else f"VEC{arr.shape[1]}"
        if name == "POSITION":
            acc["min"], acc["max"] = arr.min(axis=0).tolist(), arr.max(axis=0).tolist()
        if arr.dtype == np.uint8:
            acc["normalized"] = True
        view = {"buffer": 0, "byteOffset": len(blob), "byteLength": arr.nbytes}
        if name != "indices":
            view["target"] = 34962
        else:
            view["target"] = 34963
        views.append(view)
        accessors.append(acc)
        blob = _pad(blob + arr.tobytes(), b"\0")
        if name == "indices":
            prim["indices"] = len(accessors) - 1
        else:
            prim.setdefault("attributes", {})[name] = len(accessors) - 1
    prim["mode"] = mode
    gltf.update(
        nodes=[{**_node("fuseflow", matrix), "mesh": 0}], meshes=[{"primitives": [prim]}], accessors=accessors, bufferViews=views,
        buffers=[{"byteLength": len(blob)}],
    )  # fmt: skip
    return _glb_bytes(gltf, blob)


def _glb_bytes(gltf: dict, blob: bytes) -> bytes:
    js = _pad(json.dumps(gltf, separators=(",", ":")).encode(), b" ")
    chunks = struct.pack("<II", len(js), 0x4E4F534A) + js
    if blob:
        chunks += struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def _rgba(rgb: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 -> (M, 4) with alpha 255 (glTF wants vertex attributes 4-byte aligned)."""
    rgb = np.asarray(rgb, np.uint8).reshape(-1, 3)
    return np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)


def write_glb_points(path: str | Path, cloud: FusedCloud, up: np.ndarray | None = None) -> Path:
    """Write ``cloud`` as a glTF binary point cloud (see the module docstring); ``up``: the 4x4
    glTF-from-cloud rotation put on the node (None: none)."""
    c = cloud.numpy()
    attrs = {
        "POSITION": c.xyz.astype(np.float32),
        "COLOR_0": _rgba(c.rgb),
        "_WEIGHT": c.weight.astype(np.float32),
    }
    return write_bytes_atomic(Path(path), _glb(attrs, None, 0, up))


def write_glb_mesh(
    path: str | Path,
    vertices: np.ndarray,
    faces: np.ndarray,
    colors: np.ndarray,
    normals: np.ndarray | None = None,
    up: np.ndarray | None = None,
) -> Path:
    """Write a triangle mesh (vertices (V, 3) metres, faces (F, 3), colours (V, 3) uint8,
    optional unit normals (V, 3)) as GLB; ``up`` as for ``write_glb_points``."""
    v = np.asarray(vertices, np.float32).reshape(-1, 3)
    if len(faces) == 0:
        v = v[:0]
    attrs = {"POSITION": v, "COLOR_0": _rgba(colors)[: len(v)]}
    if normals is not None:
        attrs["NORMAL"] = np.asarray(normals, np.float32).reshape(-1, 3)[: len(v)]
    idx = np.asarray(faces, np.uint32).reshape(-1)
    return write_bytes_atomic(Path(path), _glb(attrs, idx if len(v) else None, 4, up))


def write_cloud(
    path: str | Path, cloud: FusedCloud, fmt: str = "ply", error_mm: float = DRC_ERROR_MM, up: np.ndarray | None = None
) -> Path:
    """Write ``cloud`` in ``fmt`` ("ply", "drc", "glb" or "splat") to ``path`` (its suffix is the
    caller's); ``up``: the glTF-from-cloud rotation of a GLB's node."""
    from fuseflow.io.ply import write_ply

    if fmt == "ply":
        return write_ply(path, cloud)
    if fmt == "drc":
        return write_drc(path, cloud, error_mm)
    if fmt == "glb":
        return write_glb_points(path, cloud, up)
    if fmt == "splat":
        from fuseflow.io.splat import write_splat

        return write_splat(path, cloud)
    raise ValidationError(f"cloud format must be one of {', '.join(CLOUD_FORMATS)}, got {fmt!r}")


def read_cloud(path: str | Path) -> FusedCloud:
    """Read a cloud written by ``write_cloud`` (.ply or .drc by suffix; .glb through trimesh)."""
    from fuseflow.io.ply import read_ply

    path = Path(path)
    if path.suffix == ".drc":
        return read_drc(path)
    if path.suffix == ".glb":
        return _read_glb_points(path)
    return read_ply(path)


def has_weight(path: str | Path) -> bool:
    """Whether the cloud file ``path`` stores FUSE's weight (PLY and GLB do; Draco does not, and
    ``read_cloud`` gives its points weight 1.0)."""
    return Path(path).suffix != ".drc"


def _read_glb_points(path: Path) -> FusedCloud:
    """Positions, colours and _WEIGHT of a GLB point cloud written by ``write_glb_points``."""
    data = read_bytes(path)
    if len(data) < 20 or data[:4] != b"glTF":
        raise FormatError(f"{path}: not a GLB file")
    jlen = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20 : 20 + jlen])
    blob = data[20 + jlen + 8 :]
    if not gltf.get("meshes"):
        return FusedCloud.from_numpy(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
    attrs = gltf["meshes"][0]["primitives"][0]["attributes"]

    def get(name, dtype, width):
        acc = gltf["accessors"][attrs[name]]
        view = gltf["bufferViews"][acc["bufferView"]]
        return np.frombuffer(blob, dtype, acc["count"] * width, view.get("byteOffset", 0)).reshape(acc["count"], -1)

    xyz = get("POSITION", np.float32, 3)
    rgb = get("COLOR_0", np.uint8, 4)[:, :3] if "COLOR_0" in attrs else np.zeros((len(xyz), 3))
    w = get("_WEIGHT", np.float32, 1)[:, 0] if "_WEIGHT" in attrs else np.ones(len(xyz))
    return FusedCloud.from_numpy(xyz, rgb, w, np.full(len(xyz), -1))
