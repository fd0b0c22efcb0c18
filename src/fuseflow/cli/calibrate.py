"""`fuseflow calibrate REC --out calib.json`: GMAC on one frame of a recording."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.table import Table

from fuseflow.cli.app import console, fail, say, warn


def command(
    rec: Path = typer.Argument(..., help="Recording directory (any layout `fuseflow info` reads)."),
    out: Path = typer.Option(..., "--out", "-o", help="calib.json to write."),
    frame: int = typer.Option(0, "--frame", "-t", help="Frame index to calibrate from."),
    backbone: str = typer.Option("colmap", "--backbone", help="colmap | precomputed | vggt | mapanything."),
    backbone_path: str = typer.Option(None, "--backbone-path", help="Export .npz (precomputed) or local checkpoint."),
    preset: str = typer.Option(
        "default", "--preset", help="default | paper | refined | wo_rc | wo_cc | wo_feature | zonly | full3d | robust."
    ),
    refine: bool = typer.Option(
        None, "--refine/--no-refine", help="Override the preset's ICP + pose-graph refinement."
    ),
) -> None:
    """Target-free metric extrinsics (GMAC) from one multi-view RGB-D frame."""
    import fuseflow
    from fuseflow.calib import CalibConfig
    from fuseflow.calib import calibrate as run_gmac
    from fuseflow.io.paths import check_output_file

    check_output_file(out)  # before GMAC runs: a bad --out fails in one line, not after minutes
    recording = fuseflow.open_recording(rec)
    if not 0 <= frame < len(recording):
        fail(f"--frame {frame} is out of range: the recording has {len(recording)} frames")
    overrides = {"backbone": backbone, "backbone_path": backbone_path}
    if refine is not None:
        overrides["refine"] = refine
    config = CalibConfig.preset(preset, **overrides)
    rig = fuseflow.Rig(tuple(c.with_extrinsics(None) for c in recording.rig))
    views = recording[frame]
    if views.missing and int(views.present.sum()) < 2:  # say so, rather than GMAC blaming the texture of absent views
        have = "no view" if not bool(views.present.any()) else "one view"
        fail(
            f"frame {views.index} has {have} present (missing: {', '.join(views.missing)}); "
            "GMAC needs two or more: pick another --frame"
        )
    calib = run_gmac(views, rig, config)
    fuseflow.write_calibration(out, calib, rig=recording.rig)  # its fingerprint guards reuse on another rig
    r = calib.report
    say(
        f"GMAC {rec} frame {frame}: backbone {r['backbone']}, s* = {r['scale']:.6g} "
        f"(naive median ratio {r['scale_naive_median_depth_ratio']}), {len(calib.T_cam_world)}/{len(rig)} cameras placed, "
        f"{r['timings_s']['total']:.1f} s"
    )
    t = Table("edge", "scale", "corr.", "status", box=None)  # camera ids and numbers: no markup
    for e, s in r["edge_scales"].items():
        status = "pruned" if e in r["pruned_edges"] else ("kept, gives s*" if e in r["scale_edges"] else "kept")
        t.add_row(e, f"{s:.5g}", str(r["correspondence_counts"][e]), status)
    console.print(t)
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
    say(f"wrote {out}")
