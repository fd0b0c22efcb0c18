"""`fuseflow bench ...`: the benchmarks, as calls into fuseflow.eval (no file of the source tree).

``bench_app`` is the group; its subcommands are registered in the list at the end of this module:
``fuse`` (fuseflow.eval.bench.fuse_speed), ``calib`` (fuseflow.eval.bench.calib_accuracy),
``paper`` (fuseflow.eval.paper), ``live`` (fuseflow.eval.bench.live), and one per module of
fuseflow.eval.bench whose program in ``benchmarks/`` is a thin wrapper (``calib-wide``,
``fuse-ablations``, ``calib-reference``, ``outputs``, ``sync-check``, ``calib-verdicts``, ...).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import typer

from fuseflow.cli.app import OLD_FRAMES_COUNT, fail, frame_count, guarded, progress, say

DATA_DIR_HELP = (
    "The shared data folder holding icl-livingroom1 (ICL-NUIM). Default ../shared/data, relative to the "
    "working directory (run from the project root), or the environment variable FUSEFLOW_DATA."
)


def _data_dir_option() -> Path:
    return typer.Option(Path("../shared/data"), "--data-dir", envvar="FUSEFLOW_DATA", help=DATA_DIR_HELP)


def _echo(line: str) -> None:
    typer.echo(line)


def bench_fuse(
    cameras: str = typer.Option("1,2,4,8,16", "--cameras", help="Comma list of camera counts N."),
    num_frames: int = typer.Option(7, "--num-frames", help="Timed frames per N (median over them, after warm-up)."),
    old_frames: int = OLD_FRAMES_COUNT,
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    json_out: Path = typer.Option(None, "--json", help="Write one JSON row per (method, N)."),
    no_baselines: bool = typer.Option(False, "--no-baselines", help="Time FUSE only."),
    methods_opt: str = typer.Option(
        None, "--methods", help="Comma list of methods (fuse, fuse_auto, fuse_live, vbg, naive_voxel, ...)."
    ),
    data: str = typer.Option("sim", "--data", help="Comma list of sim, icl, hocap (real 8-camera rigs, N <= 8)."),
    data_dir: Path = _data_dir_option(),
) -> None:
    """FUSE per-frame time and peak memory against VoxelBlockGrid TSDF and naive + voxel fusion."""
    frames = frame_count(num_frames, old_frames)
    from fuseflow.eval.bench import BenchmarkFailed
    from fuseflow.eval.bench.fuse_speed import DEFAULT_METHODS, parse_options, run_fuse_speed

    cams, resolution = parse_options(cameras, "640x480")
    command = f"fuseflow bench fuse --cameras {cameras} --num-frames {frames} --device {device} --data {data}"
    command += (f" --json {shlex.quote(str(json_out))}" if json_out is not None else "") + (
        " --no-baselines" if no_baselines else ""
    )
    methods = ["fuse"] if no_baselines else list(DEFAULT_METHODS)
    if methods_opt and not no_baselines:
        methods = [m.strip() for m in methods_opt.split(",") if m.strip()]
        command += f" --methods {methods_opt}"
    names = [d.strip() for d in data.split(",") if d.strip()]
    try:
        run_fuse_speed(cams, frames, device=device, methods=methods, resolution=resolution, json_path=json_out,
                       command=command, log=_echo, data=names, data_dir=data_dir)  # fmt: skip
    except BenchmarkFailed as exc:
        fail(str(exc), code=1)


def bench_calib(
    seeds: int = typer.Option(10, "--seeds", help="Seeds per data set (10 or more for stable means)."),
    data: str = typer.Option(
        "sim4,sim8,icl8",
        "--data",
        help="Comma list of sim4, sim8, icl8, symstudio (symmetric studio), far3 (far range).",
    ),
    quick: bool = typer.Option(False, "--quick", help="2 seeds on sim8 and icl8."),
    backbone: str = typer.Option(
        "colmap",
        "--backbone",
        help="colmap (COLMAP's model; calibrate's own default is auto) or perturbed (ground truth + noise: GMAC alone).",
    ),
    no_peer: bool = typer.Option(False, "--no-peer", help="Skip the Open3D multiway registration peer."),
    json_out: Path = typer.Option(None, "--json", help="Also write every per-seed row as JSON."),
    data_dir: Path = _data_dir_option(),
    seed_start: int = typer.Option(0, "--seed-start", min=0, help="First seed of symstudio / far3 (held-out seeds)."),
) -> None:
    """GMAC rotation / translation error and time per calibration, every variant and peer."""
    from fuseflow.eval.bench.calib_accuracy import run_calib_accuracy
    from fuseflow.eval.bench.calib_studio import STUDIO_DATA, run_studio_bench
    from fuseflow.eval.paper import icl_path

    if quick:
        seeds, data = 2, "sim8,icl8"
    names = [d.strip() for d in data.split(",") if d.strip()]
    studio = [d for d in names if d in STUDIO_DATA]
    names = [d for d in names if d not in STUDIO_DATA]
    if studio:  # per camera: placed / flagged / error, silently wrong (calib_studio)
        run_studio_bench(studio, seeds, json_path=json_out if not names else None, log=_echo,
                         progress=lambda line: typer.echo(line, err=True), seed_start=seed_start)  # fmt: skip
        if not names:
            return
    icl = icl_path(data_dir)
    if "icl8" in names and not icl.is_dir():
        fail(f"icl8: the ICL-NUIM data is not at {icl}; pass --data-dir (or FUSEFLOW_DATA) or leave icl8 out of --data")
    run_calib_accuracy(seeds, names, backbone, peer=not no_peer, icl=icl, json_path=json_out, log=_echo,
                       progress=lambda line: typer.echo(line, err=True))  # fmt: skip


def _paper_command(out: Path, quick: bool, tables: str, no_icl: bool) -> str:
    """The command line quoted in paper_tables.md: the one typed, else one rebuilt from the options."""
    command = "fuseflow bench paper " + " ".join(shlex.quote(a) for a in sys.argv[3:]) if len(sys.argv) > 2 else ""
    if not command.strip() or "paper" not in sys.argv:
        command = f"fuseflow bench paper --out {shlex.quote(str(out))}" + (" --quick" if quick else "")
        command += f" --tables {tables}" + (" --no-icl" if no_icl else "")
    return command


def bench_paper(
    out: Path = typer.Option(..., "--out", help="Output folder: cached cells (cells/*.json), paper_tables.md, PNG."),
    quick: bool = typer.Option(False, "--quick", help="Tiny resolution, 2 frames, 2 seeds: a few minutes (CI)."),
    tables: str = typer.Option(
        "gmac,static,dynamic,ablation,extrinsics,fps",
        "--tables",
        help="Comma list of gmac (I/III), static (IV/VI), dynamic (V), ablation (VII), extrinsics (VIII), fps (Fig. 5).",
    ),
    no_icl: bool = typer.Option(False, "--no-icl", help="Skip the ICL-NUIM virtual rig (simulated data only)."),
    data_dir: Path = _data_dir_option(),
) -> None:
    """Tables I/III, IV/VI, V, VII, VIII and Fig. 5 on simulated rigs and the ICL virtual rig.

    Resumable: each cell is cached in OUT/cells and skipped when present; delete a file to redo it.
    """
    from fuseflow.eval import paper

    names = [t.strip() for t in tables.split(",") if t.strip()]
    bad = sorted(set(names) - set(paper.TABLES))
    if not names or bad:
        fail(f"--tables: unknown {bad or 'empty list'}; choose from {', '.join(paper.TABLES)}")
    icl = not no_icl
    if icl and not paper.icl_path(data_dir).is_dir():
        fail(
            f"the ICL-NUIM data is not at {paper.icl_path(data_dir)}; pass --data-dir (or FUSEFLOW_DATA), "
            "or --no-icl to use simulated data only"
        )
    pc = paper.QUICK if quick else paper.FULL
    command = _paper_command(out, quick, tables, no_icl)
    with progress("cells") as bar:
        task = bar.add_task("cells", total=None)

        def step(i: int, n: int, key: str) -> None:
            bar.update(task, total=n, completed=i, description=key[:60])

        files = paper.run(out, pc, names, command=command, progress=step, icl=icl, data_dir=data_dir)
    say(f"computed {files['computed']} cells; tables: {files['markdown']}")
    if "fig5" in files:
        say(f"Fig. 5: {files['fig5']}")


def bench_live(
    cases: str = typer.Option("sim4,hocap8,hocap8-200k", "--cases", help="Comma list of sim4, hocap8, hocap8-200k."),
    duration: float = typer.Option(20.0, "--duration", help="Seconds each case runs."),
    data_dir: Path = _data_dir_option(),
    json_out: Path = typer.Option(None, "--json", help="Write the rows and the machine here."),
    stand_in_ms: float = typer.Option(
        None, "--stand-in-ms", help="Replace FUSE by a sleep of this many ms returning a real cloud (all but FUSE)."
    ),
    codec: str = typer.Option("compact", "--codec", help="The viewer's frame codec: compact or raw."),
) -> None:
    """Replays through `fuseflow live --serve` with one viewer: fps, drops, latency, Mbit/s."""
    from fuseflow.eval.bench.live import run_live_bench

    command = f"fuseflow bench live --cases {cases} --duration {duration:g}"
    command += f" --json {shlex.quote(str(json_out))}" if json_out is not None else ""
    command += f" --stand-in-ms {stand_in_ms:g}" if stand_in_ms is not None else ""
    command += f" --codec {codec}" if codec != "compact" else ""
    names = [c.strip() for c in cases.split(",") if c.strip()]
    run_live_bench(
        names, duration, data_dir, json_out, command=command, log=_echo, stand_in_ms=stand_in_ms, codec=codec
    )


def bench_fuse_ratio(
    recordings: list[Path] = typer.Argument(..., help="Recordings (fuseflow format); the first frame of each."),
    preset: str = typer.Option("auto", "--preset", help="FUSE preset."),
    rounds: int = typer.Option(5, "--rounds", help="Interleaved FUSE / VBG rounds (median ratio over them)."),
    json_out: Path = typer.Option(None, "--json", help="Write the rows as JSON."),
) -> None:
    """FUSE vs VoxelBlockGrid 1 cm as an interleaved time ratio (robust to a loaded machine)."""
    import json

    from fuseflow.eval.bench.fuse_ratio import run_fuse_ratio

    rows = run_fuse_ratio(recordings, preset, rounds, log=_echo)
    if json_out is not None:
        json_out.write_text(json.dumps(rows, indent=1))


def bench_fuse_quality(
    cameras: str = typer.Option("3,4,8", "--cameras", help="Comma list of ring sizes."),
    resolutions: str = typer.Option("320x240,640x480", "--resolutions", help="Comma list of WxH."),
    seeds: str = typer.Option("11,29,47,61,73,89", "--seeds", help="Comma list of simulator seeds."),
    kinds: str = typer.Option("static,dynamic", "--kinds", help="static, dynamic or both."),
    methods: str = typer.Option(
        "auto,vbg,naive",
        "--methods",
        help="FUSE presets (PRESET+NAME=VALUE changes a setting), vbg, naive; the first is compared.",
    ),
    num_frames: int = typer.Option(1, "--num-frames", help="Frames per cell (mean over them)."),
    json_out: Path = typer.Option(None, "--json", help="Write the rows and the per-rig summary as JSON."),
) -> None:
    """FUSE vs VoxelBlockGrid: precision / recall / F at 5 mm, 1 cm, 2 cm on simulated rings."""
    import json

    from fuseflow.eval.bench.fuse_quality import run_fuse_quality, summarize_quality

    def ints(text: str) -> list[int]:
        try:
            return [int(v) for v in text.split(",") if v.strip()]
        except ValueError:
            fail(f"expected a comma list of integers, got {text!r}")

    try:
        res = [tuple(int(v) for v in r.lower().split("x")) for r in resolutions.split(",") if r.strip()]
    except ValueError:
        fail(f"--resolutions: expected WxH[,WxH...], got {resolutions!r}")
    dyn = [{"static": False, "dynamic": True}.get(k.strip(), k) for k in kinds.split(",") if k.strip()]
    if any(not isinstance(d, bool) for d in dyn):
        fail(f"--kinds: expected static and/or dynamic, got {kinds!r}")
    names = [m.strip() for m in methods.split(",") if m.strip()]
    rows = run_fuse_quality(ints(cameras), res, ints(seeds), dyn, names, num_frames, log=_echo)
    summary = summarize_quality(rows)
    for s in summary:
        m = s["method"]
        say(f"{s['cameras']}-ring {s['resolution']}: {m} F@1cm {s[f'{m}_f_1cm']:.3f}, VBG {s.get('vbg_f_1cm', float('nan')):.3f}: "
            f"{m} >= VBG in {s['wins']} of {s['cells']} cells")  # fmt: skip
    if json_out is not None:
        cmd = "fuseflow bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        json_out.write_text(json.dumps({"command": cmd, "rows": rows, "summary": summary}, indent=1))


def _int_list(text: str, option: str) -> tuple[int, ...]:
    """A comma list of integers, or a one-line error naming ``option``."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        fail(f"{option}: expected a comma list of integers, got {text!r}")


def _names(text: str) -> list[str]:
    return [v.strip() for v in text.split(",") if v.strip()]


def bench_calib_wide(
    what: str = typer.Argument(..., help="sim, hocap, icl, pairs (2-camera rigs) or summary (table of --out)."),
    out: Path = typer.Option(Path("benchmarks/results/calib_wide.jsonl"), "--out", help="JSON lines file (appended)."),
    work: Path = typer.Option(Path("/tmp/fuseflow-calib-wide"), "--work", help="Folder for the recordings it makes."),
    cameras: str = typer.Option("3,4,6,8", "--cameras", help="Comma list of ring sizes (sim, pairs)."),
    scenes: str = typer.Option("room,studio", "--scenes", help="Comma list of simulated scenes."),
    seeds: str = typer.Option("1,2,3", "--seeds", help="Comma list of simulator seeds."),
    num_frames: int = typer.Option(5, "--num-frames", help="Frames simulated (runs use 1 and all of them)."),
    only_frames: int = typer.Option(None, "--only-frames", help="Run only with this many frames."),
    dynamic: bool = typer.Option(False, "--dynamic", help="Simulate moving objects."),
    resolution: str = typer.Option("640x480", "--resolution", help="Simulated WxH."),
    every: str = typer.Option("26", "--every", help="Comma list of ICL frame steps (icl, pairs)."),
    backbone: str = typer.Option("raw", "--backbone", help="raw (rgbd_backbone alone), colmap, rgbd or auto."),
    matcher: str = typer.Option("sift", "--matcher", help="The rgbd backbone's image matcher."),
    data_dir: Path = typer.Option(
        Path("../shared/data"),
        "--data-dir",
        envvar="FUSEFLOW_DATA",
        help="The folder holding hocap-8rs and icl-livingroom1.",
    ),
) -> None:
    """The metric RGB-D backbone on wide-baseline rigs against ground truth (rows as JSON lines)."""
    from fuseflow.eval.bench.calib_wide import MATCHERS, WHAT, WideOptions, run_calib_wide

    if what not in WHAT or backbone not in ("raw", "colmap", "rgbd", "auto") or matcher not in MATCHERS:
        fail(f"expected WHAT in {', '.join(WHAT)}, --backbone raw|colmap|rgbd|auto, --matcher {'|'.join(MATCHERS)}")
    opts = WideOptions(out=out, data=work, shared=data_dir, cameras=_int_list(cameras, "--cameras"),
                       scenes=tuple(_names(scenes)), seeds=_int_list(seeds, "--seeds"), frames=num_frames,
                       only_frames=only_frames, dynamic=dynamic, resolution=resolution,
                       every=_int_list(every, "--every"), backbone=backbone, matcher=matcher)  # fmt: skip
    run_calib_wide(what, opts, log=_echo)


def bench_fuse_ablations(
    num_frames: int = typer.Option(2, "--num-frames", help="Frames per rig (mean over them)."),
    density_frames: int = typer.Option(1, "--density-frames", help="Frames of the density rows."),
    seed: int = typer.Option(11, "--seed", help="Simulator seed."),
    resolution: str = typer.Option("640x480", "--resolution", help="WxH."),
    cameras: int = typer.Option(8, "--cameras", help="Cameras of the ring."),
    no_density: bool = typer.Option(False, "--no-density", help="Skip the density / quality trade-off rows."),
    only: str = typer.Option(None, "--only", help="Comma list of row names (default: every row)."),
    json_out: Path = typer.Option(None, "--json", help="Write meta, rows and density rows as JSON."),
) -> None:
    """FUSE, its ablations and switches, VoxelBlockGrid and naive fusion against the GT surface."""
    import json

    from fuseflow.eval.bench.fuse_ablations import run_fuse_ablations

    try:
        w, h = (int(v) for v in resolution.lower().split("x"))
    except ValueError:
        fail(f"--resolution: expected WxH, got {resolution!r}")
    command = "fuseflow bench " + " ".join(shlex.quote(a) for a in sys.argv[2:])
    out = run_fuse_ablations(num_frames, density_frames, seed, (w, h), cameras, not no_density,
                             _names(only) if only else None, command, log=_echo)  # fmt: skip
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(out, indent=1) + "\n")
        say(f"wrote {json_out}")


def bench_calib_reference(
    data: list[str] = typer.Argument(..., help="hocap (hocap-8rs under --data-dir) or recording paths (frame 0)."),
    per_camera: bool = typer.Option(
        False, "--per-camera", help="Score each camera's pose against the reference's others."
    ),
    data_dir: Path = typer.Option(
        Path("../shared/data"), "--data-dir", envvar="FUSEFLOW_DATA", help="The folder holding hocap-8rs."
    ),
) -> None:
    """Calibration vs the data set's reference: which pose set fits the depth and the colours better."""
    import json

    from fuseflow.eval.bench.calib_reference import per_camera_table, reference_table

    if per_camera:
        for name in data:
            per_camera_table(name, data_dir, log=_echo)
        return
    reference_table(data, data_dir, log=_echo, record=lambda row: typer.echo(json.dumps(row), err=True))


def bench_outputs(
    what: str = typer.Argument(..., help="crop (--crop auto), formats (--format sizes, Draco error) or mesh (--mesh)."),
    recordings: list[str] = typer.Argument(..., help="Recordings (crop and mesh: simulated, with gt/)."),
    error_mm: float = typer.Option(1.0, "--error-mm", help="formats: Draco's position error bound (mm)."),
    methods: str = typer.Option("tsdf,poisson,bpa", "--methods", help="mesh: comma list of meshing methods."),
    repeats: int = typer.Option(3, "--repeats", help="mesh: timed runs per method."),
    threads: int = typer.Option(2, "--threads", help="mesh: torch threads."),
) -> None:
    """The output options on frame 0: crop keeps / drops, file sizes and Draco error, mesh time and accuracy."""
    import json

    from fuseflow.eval.bench import outputs

    if what not in ("crop", "formats", "mesh"):
        fail(f"expected WHAT crop, formats or mesh, got {what!r}")
    if what == "mesh":
        import torch

        torch.set_num_threads(threads)
    for r in recordings:
        if what == "crop":
            m = outputs.crop_quality(r)
            _echo(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in m.items()}))
            continue
        rows = (
            outputs.format_sizes(r, error_mm)
            if what == "formats"
            else outputs.mesh_quality(r, _names(methods), repeats)
        )
        for row in rows:
            _echo(json.dumps(row))


def bench_sync_check(
    root: Path = typer.Argument(..., help="Folder for the simulated recordings (kept and reused)."),
    seeds: int = typer.Option(5, "--seeds", help="Seeds per config."),
    fps: float = typer.Option(30.0, "--fps", help="Simulated frame rate."),
    num_frames: int = typer.Option(20, "--num-frames", help="Frames per recording."),
    configs: str = typer.Option(None, "--configs", help="Comma list of configs (default: all of them)."),
    method: str = typer.Option("auto", "--method", help="auto, covisible or agreement."),
    first_seed: int = typer.Option(0, "--first-seed", help="First seed."),
) -> None:
    """The camera-sync check against simulated offsets: exact, false alarms, seconds per check."""
    from fuseflow.eval.bench.sync_check import CONFIGS, run_sync_check

    names = _names(configs) if configs else list(CONFIGS)
    run_sync_check(root, seeds, fps, num_frames, names, method, first_seed, log=_echo)


def bench_calib_verdicts(
    cameras: str = typer.Option("4,6", "--cameras", help="Comma list of ring sizes."),
    seeds: str = typer.Option("1,2", "--seeds", help="Comma list of simulator seeds."),
    json_out: Path = typer.Option(None, "--json", help="Write the per-camera rows as JSON."),
) -> None:
    """Per-camera verdict and expected accuracy of calibrate against the true error (simulated rings)."""
    import json

    from fuseflow.eval.bench.calib_verdicts import run_calib_verdicts, verdict_summary

    rows = run_calib_verdicts(_int_list(cameras, "--cameras"), _int_list(seeds, "--seeds"), log=lambda r: _echo(str(r)))
    line = verdict_summary(rows)
    if line is not None:
        say(line)
    if json_out is not None:
        json_out.write_text(json.dumps(rows, indent=1))


bench_app = typer.Typer(
    help="Benchmarks: speed / quality tables measured on this machine.", no_args_is_help=True, rich_markup_mode=None
)
for _name, _command in (
    ("fuse", bench_fuse),
    ("fuse-ratio", bench_fuse_ratio),
    ("fuse-quality", bench_fuse_quality),
    ("calib", bench_calib),
    ("paper", bench_paper),
    ("live", bench_live),
    ("calib-wide", bench_calib_wide),
    ("fuse-ablations", bench_fuse_ablations),
    ("calib-reference", bench_calib_reference),
    ("outputs", bench_outputs),
    ("sync-check", bench_sync_check),
    ("calib-verdicts", bench_calib_verdicts),
):
    bench_app.command(_name)(guarded(_command))
