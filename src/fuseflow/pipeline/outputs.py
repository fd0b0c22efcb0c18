"""The output directory of a run: where clouds go, the per-frame log (frames.jsonl) that lets a
run resume, the summary, and the manifest (manifest.json) that says what produced the
directory, so that a run resumes only its own work. Every file is written atomically (an
interrupted run leaves only complete files)."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import os
import re
import resource
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fuseflow.errors import OutputError
from fuseflow.io.convert import CAMERA_FILE_SUFFIXES
from fuseflow.pipeline.records import FrameRecord

__all__ = [
    "cloud_path",
    "read_frame_log",
    "peak_rss_mb",
    "OutputManifest",
    "open_output",
    "recording_fingerprint",
    "calibration_digest",
    "config_digest",
    "settings_doc",
    "settings_digest",
    "setting_changes",
    "MANIFEST",
    "fuseflow_version",
    "lock_output",
    "recording_files",
]


def cloud_path(out_dir: str | Path, index: int) -> Path:
    """Where ``run`` writes the cloud of frame ``index``: OUT/clouds/<index:06d>.ply."""
    return Path(out_dir) / "clouds" / f"{index:06d}.ply"


def read_frame_log(path: Path) -> dict[int, FrameRecord]:
    """The records of frames.jsonl by frame number; lines cut by an interruption are skipped."""
    previous: dict[int, FrameRecord] = {}
    if not path.exists():
        return previous
    for line in path.read_text().splitlines():
        try:
            r = FrameRecord.from_json(json.loads(line))
        except (json.JSONDecodeError, KeyError, ValueError, TypeError):
            continue  # a line cut by an interruption
        previous[r.index] = r
    return previous


def peak_rss_mb() -> float:
    """Peak resident memory of this process, MB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


MANIFEST = "manifest.json"
"""The file in OUT that says what produced it (``OutputManifest``)."""

_OUTPUTS = ("clouds", "meshes", "splats", "frames.jsonl", "summary.json", "calib.json", MANIFEST)
"""What a run or fuse writes in OUT (``--force`` removes exactly these)."""


def _digest(doc: Any) -> str:
    """Short SHA-256 of a JSON-able document (sorted keys: same content, same digest)."""
    text = json.dumps(doc, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fuseflow_version() -> str:
    try:
        return importlib.metadata.version("fuseflow")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


@dataclass(frozen=True)
class OutputManifest:
    """What produced an output directory: a resume is allowed only when this matches."""

    command: str
    """"run" or "fuse"."""
    recording: str
    """The recording's resolved path (informative: a moved recording with the same content resumes)."""
    recording_fingerprint: str
    """Digest of the rig (rig.json: ids, intrinsics, resolution, extrinsics), the frame list and
    each data file's size and modification time (``recording_fingerprint``)."""
    calibration: str
    """Where the extrinsics come from: "rig.json", "given:<digest of the extrinsics>" or
    "gmac:<digest of CalibConfig>:frame=<position or first-good>"."""
    config: str
    """Digest of the settings that change the outputs (FUSE, GMAC, health, recalibration)."""
    fuseflow_version: str
    settings: dict[str, Any] | None = None
    """The settings ``config`` digests, by name (``settings_doc``), so that a mismatch can say which
    setting changed; None in manifests written before it was recorded."""

    def differences(self, other: OutputManifest) -> list[str]:
        """Human-readable differences that forbid resuming ``other`` as ``self`` (path excluded);
        changed settings are named one by one ("settings: fuse.s0 was 5.0, now 1.0")."""
        names = {
            "command": "command",
            "recording_fingerprint": "recording content (rig.json, frame list, or a file's size or modification time)",
            "calibration": "calibration",
            "config": "settings",
            "fuseflow_version": "fuseflow version",
        }
        out = []
        for key, what in names.items():
            a, b = getattr(other, key), getattr(self, key)
            if a == b:
                continue
            named = setting_changes(other.settings, self.settings) if key == "config" else []
            if named:
                out.extend(f"{what}: {change}" for change in named)
            else:
                out.append(f"{what}: was {a}, now {b}")
        return out


def _flat(doc: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(doc, dict):
        flat: dict[str, Any] = {}
        for k, v in doc.items():
            flat.update(_flat(v, f"{prefix}{k}."))
        return flat
    return {prefix[:-1]: doc}


def setting_changes(old: dict[str, Any] | None, new: dict[str, Any] | None) -> list[str]:
    """ "NAME was X, now Y" for every setting that differs between two ``settings_doc`` documents
    (nested names joined by dots); [] when either is unknown."""
    if old is None or new is None:
        return []
    a = _flat(json.loads(json.dumps(_resumable(old), default=str)))
    b = _flat(json.loads(json.dumps(_resumable(new), default=str)))
    missing = object()
    return [
        f"{k} was {a.get(k, 'unset')!r}, now {b.get(k, 'unset')!r}"
        for k in sorted(set(a) | set(b))
        if a.get(k, missing) != b.get(k, missing)
    ]


_DATA_FILES = (
    ".png",
    ".jpg",
    ".jpeg",
    ".pgm",
    ".ppm",
    ".tif",
    ".tiff",
    ".exr",
    ".json",
    ".txt",
    ".log",
    *CAMERA_FILE_SUFFIXES,
)


def recording_files(path: str | Path) -> list[tuple[str, int, int]]:
    """(relative path, size, mtime in ns) of the data files of a recording (images, JSON, lists,
    .bag / .mkv), sorted; folders holding a FuseFlow output (a manifest.json) and hidden ones
    are left out, so an --out inside the recording does not change it."""
    root = Path(path)
    if root.is_file():
        st = root.stat()
        return [(root.name, st.st_size, st.st_mtime_ns)]
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and not (Path(folder) / d / MANIFEST).exists())
        for name in files:
            if name.lower().endswith(_DATA_FILES) and not name.startswith("."):
                try:
                    st = os.stat(os.path.join(folder, name))
                except OSError:
                    continue
                found.append((os.path.relpath(os.path.join(folder, name), root), st.st_size, st.st_mtime_ns))
    return sorted(found)


def recording_fingerprint(rec) -> str:
    """Digest of a recording's rig, frame list and files' sizes and modification times
    (``OutputManifest.recording_fingerprint``): a frame file replaced after a run changes it."""
    from fuseflow.io.recording import rig_to_json

    files = recording_files(rec.path) if getattr(rec, "path", None) else []
    return _digest({"rig": rig_to_json(rec.rig), "frames": list(rec.frame_numbers), "files": files})


def calibration_digest(T_cam_world: dict[str, np.ndarray]) -> str:
    """Digest of extrinsics (rounded to 1e-9 m / rad: the same calibration read back from JSON
    matches)."""
    return _digest({c: np.round(np.asarray(T, dtype=np.float64), 9).tolist() for c, T in sorted(T_cam_world.items())})


def settings_doc(**configs: Any) -> dict[str, Any]:
    """The settings of a run by name, each a dataclass config (as its fields) or a plain value:
    what ``OutputManifest.settings`` records and ``settings_digest`` digests."""
    return {k: _plain(c) for k, c in configs.items()}


ADDABLE = ("cloud_format",)
"""Output settings a later call may change and still resume: the cloud formats (a frame missing
a newly asked format is fused again and written in every format)."""


def _resumable(doc: Any) -> Any:
    """``doc`` without the ``ADDABLE`` settings; an ``outputs`` entry that is then the default
    is left out, as the default outputs are (``run_manifest``)."""
    if not isinstance(doc, dict):
        return doc
    out = {k: _resumable(v) for k, v in doc.items() if k not in ADDABLE}
    for key in ("outputs",):
        if isinstance(out.get(key), dict) and out[key] == _default_outputs():
            out.pop(key)
    if isinstance(out.get("pipeline"), dict):
        inner = out["pipeline"]
        if isinstance(inner.get("outputs"), dict) and inner["outputs"] == _default_outputs():
            out["pipeline"] = {k: v for k, v in inner.items() if k != "outputs"}
    return out


def _default_outputs() -> dict[str, Any]:
    from fuseflow.pipeline.config import OutputOptions

    return {k: v for k, v in dataclasses.asdict(OutputOptions()).items() if k not in ADDABLE}


def settings_digest(doc: dict[str, Any]) -> str:
    """Digest of a ``settings_doc`` (``OutputManifest.config``), the ``ADDABLE`` settings left
    out: adding a cloud format to a finished call resumes it."""
    return _digest(_resumable(doc))


def config_digest(*configs: Any) -> str:
    """Digest of dataclass configs (None for defaults is spelled out by the caller)."""
    return _digest([_plain(c) for c in configs])


def _plain(config: Any) -> Any:
    """A config as plain data: its ``as_dict()`` where it has one (the form its files record, e.g.
    CalibConfig's, which leaves default sub-configs out), else its dataclass fields, else itself."""
    if hasattr(config, "as_dict"):
        return config.as_dict()
    return dataclasses.asdict(config) if dataclasses.is_dataclass(config) else config


def _used(out: Path) -> bool:
    return any((out / name).exists() for name in _OUTPUTS if name not in ("clouds", "meshes", "splats")) or any(
        any(out.glob(f"clouds/*.{ext}")) for ext in ("ply", "drc", "glb")
    )


_FRAME_FILE = re.compile(r"^\d{6}\.[a-z]+(\.tmp)?$")
"""The per-frame files a run or fuse writes in clouds/ and meshes/ (<frame:06d>.<ext>)."""


def _clear(out: Path) -> None:
    """Remove the earlier outputs: the top-level files of ``_OUTPUTS`` and the frame files in
    clouds/ and meshes/; any other file there (not FuseFlow's) is kept, and the folder with it."""
    for name in _OUTPUTS:
        p = out / name
        if p.is_dir():
            for f in p.iterdir():
                if f.is_file() and _FRAME_FILE.match(f.name):
                    f.unlink()
            if not any(p.iterdir()):
                p.rmdir()
        elif p.exists():
            p.unlink()


_HELD: dict[Path, int] = {}  # OUT -> descriptor of OUT itself, locked until the process ends


def lock_output(out: Path) -> None:
    """Take OUT's lock (``fcntl.flock`` on the directory OUT itself, released by the system when
    this process ends, however it ends: no file is left behind); OutputError when another process
    holds it. Taking it again in the same process is a no-op."""
    import fcntl

    key = Path(out).resolve()
    if key in _HELD:
        return
    try:
        fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY)
    except OSError as exc:
        raise OutputError(f"{out}: cannot open the output directory to lock it ({exc.strerror or exc})") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise OutputError(
            f"{out} is being written by another fuseflow process: wait for it to finish, or choose another --out"
        ) from None
    _HELD[key] = fd


def open_output(out: Path, manifest: OutputManifest, force: bool = False) -> bool:
    """Make ``out`` ready for a run described by ``manifest``; True when it resumes earlier work.

    A new or empty directory starts fresh. A used one resumes only when its manifest matches
    (same command, recording content, calibration, settings and version); otherwise OutputError
    says what differs and offers ``--force``. Another process writing OUT (``lock_output``) is an
    OutputError before anything is read or written. ``force`` removes the earlier outputs (only the
    files FuseFlow writes) and starts over. The manifest is written before any other output.
    """
    from fuseflow.io.recording import write_json_atomic

    lock_output(out)
    resumed = False
    if force:
        _clear(out)
    elif (out / MANIFEST).exists():
        try:
            doc = json.loads((out / MANIFEST).read_text())
            fields = {f.name for f in dataclasses.fields(OutputManifest)}
            old = OutputManifest(**{k: v for k, v in doc.items() if k in fields})  # "sequence": exports.py
        except (json.JSONDecodeError, TypeError, AttributeError, OSError) as exc:
            raise OutputError(f"{out / MANIFEST}: unreadable ({exc}); use --force to start over") from None
        diff = manifest.differences(old)
        if diff:
            raise OutputError(
                f"{out} holds the outputs of a different {old.command} ({'; '.join(diff)}); "
                "choose another --out, or pass --force to delete them and start over"
            )
        resumed = True
    elif _used(out):
        raise OutputError(
            f"{out} already holds outputs with no {MANIFEST} (an older fuseflow or another tool): "
            "choose another --out, or pass --force to delete them and start over"
        )
    write_json_atomic(out / MANIFEST, dataclasses.asdict(manifest))
    return resumed
