"""`fuseflow live SOURCE --calib calib.json --serve 8080`: cameras in, one fused cloud out, live."""

from __future__ import annotations

import math
import signal
from contextlib import contextmanager
from pathlib import Path

import typer

from fuseflow.cli import output_options as oo
from fuseflow.cli.app import (
    OLD_FRAMES_COUNT,
    POINTS_HELP,
    check_device,
    check_fuse_options,
    fail,
    frame_count,
    print_table,
    say,
    warn,
)


def _print_summary(result, source: str) -> None:
    s = result.summary
    lat = "-" if s.latency_ms_p50 is None else f"p50 {s.latency_ms_p50:.0f} ms, p95 {s.latency_ms_p95:.0f} ms"
    rows = [
        ("source", source),
        ("stopped by", s.stopped_by),
        ("frames", f"{s.frames_in} in, {s.frames_out} fused, {s.dropped} dropped ({s.drop_rate:.1%})"),
        ("rate", f"{s.fps:.2f} fused frames/s over {s.wall_s:.1f} s; FUSE {s.fuse_ms_median or 0:.0f} ms median"),
        ("latency", f"{lat} (capture to sent)"),
        ("points per frame", f"{s.points_mean:.0f}"),
    ]
    if s.dropped_views:
        rows.append(("dropped views", ", ".join(f"{c}: {n} frames" for c, n in s.dropped_views.items())))
    for k, c in enumerate(result.clients):
        age = f", shown {c['age_ms_max']:.0f} ms old at most" if c.get("age_ms_max") else ""
        rows.append((f"viewer {k + 1}", f"{c['codec']}: {c['frames_sent']} frames sent, {c['dropped']} dropped, "
                     f"{c['mbit_per_s']:.1f} Mbit/s{age}"))  # fmt: skip
    if result.held_s:
        rows.append(("held", f"last frame served {result.held_s:.1f} s after the source ended, "
                     f"until {result.hold_ended_by}"))  # fmt: skip
    if result.encode_ms_median is not None:
        rows.append(("encoding", f"{result.encode_ms_median:.1f} ms median per frame (encoder thread), "
                     f"{result.encoder_skipped} frames not encoded"))  # fmt: skip
    rows += _capture_rows(s.capture)
    print_table("FuseFlow live", rows)
    for w in s.warnings:
        warn(w)


def _capture_rows(capture: dict) -> list[tuple[str, str]]:
    """Per capture node: state, clock offset +- uncertainty, bytes per frame; the largest camera skew."""
    rows = []
    for name, n in (capture.get("nodes") or {}).items():
        clock = f"clock {n['offset_ms']:+.1f} ms +- {n['uncertainty_ms']:.1f}" if "offset_ms" in n else "clock unknown"
        size = f"{n['bytes_per_frame'] / 1e3:.0f} kB/frame" if n.get("bytes_per_frame") else "no frames"
        size += f" {n['wire']} ({n['link']})" if n.get("wire") else ""
        rows.append((f"node {name}", f"{n['state']}, cameras {', '.join(n['cameras'])}; {clock}; {size}; "
                     f"encode {n['encode_ms']} ms, decode {n['decode_ms']} ms"))  # fmt: skip
    skew = {c: v for c, v in (capture.get("skew") or {}).items() if v}
    if skew:
        worst = max(skew, key=lambda c: skew[c]["median_ms"])
        rows.append(("camera skew", f"median |skew| at most {skew[worst]['median_ms']:.1f} ms ({worst}), "
                     f"frame interval {capture['frame_interval_ms']:.1f} ms"))  # fmt: skip
        drifts = {c: v["drift_ms"] for c, v in skew.items() if v.get("drift_ms") is not None}
        if drifts:
            far = max(drifts, key=lambda c: abs(drifts[c]))
            rows.append(("camera drift", f"at most {drifts[far]:+.1f} ms from the other cameras ({far}); warned "
                         f"above half the frame interval"))  # fmt: skip
    return rows


def _check_replay(source, calibration, settings) -> list[str]:
    """A replayed recording's first frame through ``pipeline.checks.validate_inputs`` (as fuse and
    run check theirs) before the loop starts; a camera source is not read ahead."""
    rec = getattr(source, "rec", None)
    if rec is None or not len(rec):
        return []
    from fuseflow.fuse.presets import preset_config
    from fuseflow.live.app import rig_for_live
    from fuseflow.pipeline.checks import validate_inputs
    from fuseflow.pipeline.exports import resolve_crop

    rig = rig_for_live(source.rig, calibration)
    volume = resolve_crop(settings.crop, rig, calibration)
    return validate_inputs(rec[0], rig, preset_config(settings.preset, settings.points), volume)


RAY_OPTION = typer.Option(
    None, "--ray", help="HOST:PORT (or auto) of a Ray cluster: fuse the cameras of its capture nodes (fuseflow node)."
)
FRAME_CODEC_OPTION = typer.Option(
    "auto",
    "--frame-codec",
    help="--ray: how frames travel: auto (raw from nodes on this machine, the node's JPEG/PNG colour with lossless "
    "depth from others), raw, raw16 (raw colour, 16-bit depth units), lz4 (raw colour, LZ4 depth), jpeg or png.",
)


def command(
    source: list[str] = typer.Argument(
        None,
        help="realsense[:SERIAL,...] | orbbec[:SERIAL,...] | a recording directory | .bag/.mkv files "
        "(none with --ray: the capture nodes' cameras).",
    ),
    calib: Path = typer.Option(
        None, "--calib", help="Extrinsics (calib.json from fuseflow calibrate); a replayed rig.json's otherwise."
    ),
    preset: str = typer.Option("live", "--preset", help="FUSE preset: live (every 2nd pixel), default, fast, ..."),
    points: int = typer.Option(None, "--points", help=POINTS_HELP),
    device: str = typer.Option("cpu", "--device", help="cpu or cuda."),
    num_frames: int = typer.Option(None, "--num-frames", help="Stop after N frames from the source."),
    old_frames: int = OLD_FRAMES_COUNT,
    duration: float = typer.Option(None, "--duration", help="Stop after this many seconds."),
    loop: bool = typer.Option(False, "--loop", help="Replay: start again after the last frame."),
    rate: float = typer.Option(None, "--rate", help="Replay: frames per second (default: the recording's timestamps)."),
    preload: bool = typer.Option(False, "--preload", help="Replay: decode every frame into memory first."),
    serve: str = typer.Option(
        None, "--serve", help="[HOST:]PORT: web viewer at /, frames at /ws, /stats (host default 127.0.0.1)."
    ),
    rerun: str = typer.Option(None, "--rerun", help="spawn | rerun+http://HOST:PORT/proxy | FILE.rrd"),
    record: Path = typer.Option(None, "--record", help="Write the fused clouds here (clouds/<n>.ply, as run)."),
    crop: str = oo.CROP,
    codec: str = typer.Option(
        "compact", "--codec", help="Frame codec of the viewer stream: compact (about 0.9-1.5 bytes a point) or raw (9)."
    ),
    grid_mm: float = typer.Option(
        3.0, "--grid-mm", help="compact: position grid step in mm (positions at most half a step off per axis)."
    ),
    hold: bool = typer.Option(
        False, "--hold", help="After a replay ends, keep serving its last frame until Ctrl-C or SIGTERM."
    ),
    allow_origin: list[str] = typer.Option(
        None, "--allow-origin", help="Another page (scheme://host[:port]) that may use /ws and /stats; repeatable."
    ),
    token: str = typer.Option(
        "auto", "--token", help="Viewer token: auto (random when the host is not loopback), none, or your own."
    ),
    max_viewers: int = typer.Option(16, "--max-viewers", help="WebSocket viewers at once (more get 503)."),
    ray: str = RAY_OPTION,
    nodes: int = typer.Option(None, "--nodes", help="--ray: wait for this many capture nodes (default: those there)."),
    wait: float = typer.Option(30.0, "--wait", help="--ray: seconds to wait for the capture nodes."),
    frame_codec: str = FRAME_CODEC_OPTION,
) -> None:
    """Fuse cameras (or a recording replayed as cameras) live; serve, log or record the clouds.

    Example: fuseflow live rec/ --calib calib.json --serve 8080 --loop, then open
    http://127.0.0.1:8080/ in a browser. Cameras: fuseflow live realsense --calib calib.json
    --serve 8080. Ctrl-C (or the end of a replay) stops it with a summary.
    """
    from fuseflow.io import read_calibration
    from fuseflow.live import StopRequest, run_live
    from fuseflow.live.loop import LiveSettings

    _check_options(device, crop, preset, points)
    frames = frame_count(num_frames, old_frames)
    _check_limits(frames, duration)
    outputs = _outputs(serve, rerun, record, codec, grid_mm, _access(allow_origin, token, max_viewers), hold)
    calibration = read_calibration(calib) if calib is not None else None
    settings = LiveSettings(preset=preset, points=points, device=device, frames=frames, duration=duration, crop=crop)
    opened = _open(source, (ray, nodes, wait, frame_codec), rate, loop, preload)
    try:
        checked = _check_replay(getattr(opened, "source", opened), calibration, settings)
    except BaseException:
        opened.close()
        raise

    def started(url, warnings) -> None:
        for w in [*checked, *warnings]:
            warn(w)
        say(f"live: {opened.description}" + (f"; viewer at {url}" if url else "") + " (Ctrl-C stops)")

    stop = StopRequest()
    with _signals(stop):
        result = run_live(opened, calibration, settings, outputs, on_start=started, stop=stop)
    _print_summary(result, opened.description)


def _check_options(device, crop, preset, points) -> None:
    check_device(device)
    if crop is not None and crop not in ("auto", "off"):
        from fuseflow.geometry.volume import parse_crop

        parse_crop(crop)  # a bad box fails in one line before the source opens
    check_fuse_options(preset, points)


def _open(source, ray_options, rate, loop, preload):
    """SOURCE opened here, or (``--ray``) the frames of the capture nodes on a Ray cluster."""
    from fuseflow.live import ReplayOptions, open_source

    ray, nodes, wait, frame_codec = ray_options
    if ray is None:
        if not source:
            fail("give a SOURCE (realsense, orbbec, a recording, .bag/.mkv files), or --ray ADDRESS for capture nodes")
        return open_source(source, ReplayOptions(rate=rate, loop=loop, preload=preload))
    if source:
        fail(
            "--ray fuses the cameras of the capture nodes: give no SOURCE (start fuseflow node SOURCE on each capture PC)"
        )
    if nodes is not None and nodes < 1:
        fail(f"--nodes must be a positive integer, got {nodes}")
    if not wait > 0:
        fail(f"--wait must be a positive number of seconds, got {wait}")
    from fuseflow.live.sources.ray_source import FRAME_CODECS, RayLiveOptions, RaySource

    if frame_codec not in FRAME_CODECS:
        fail(f"--frame-codec must be one of {', '.join(FRAME_CODECS)}, got {frame_codec!r}")
    options = RayLiveOptions(address=ray, nodes=nodes, wait_s=wait, frame_codec=frame_codec)
    return RaySource(options, warn=lambda m: warn(m, stderr=True))


def _check_limits(frames, duration) -> None:
    for name, value in (("--num-frames", frames), ("--duration", duration)):
        if value is not None and not math.isfinite(value):
            fail(f"{name} must be a finite number, got {value}")
        if value is not None and value <= 0:
            fail(f"{name} must be positive, got {value}")


def _outputs(serve, rerun, record, codec: str, grid_mm: float, access, hold: bool):
    from fuseflow.live import LiveOutputs, parse_address
    from fuseflow.live.codec import CompactParams
    from fuseflow.live.wire import CODECS

    if serve is not None and not serve.strip():
        fail("--serve expects [HOST:]PORT (e.g. 8080 or 0.0.0.0:8080), got an empty value")
    if codec not in CODECS:
        fail(f"--codec must be one of {', '.join(CODECS)}, got {codec!r}")
    compact = CompactParams(step_mm=grid_mm).check()
    if hold and not serve:
        fail("--hold keeps the viewer serving the last frame: give --serve [HOST:]PORT too")
    address = parse_address(serve) if serve is not None else None
    return LiveOutputs(address, rerun, record, codec, compact, access, hold)


def _access(allow_origin, token: str, max_viewers: int):
    from fuseflow.live.server import Access

    tok = None if token == "none" else token
    if tok is not None and tok != "auto" and (len(tok) < 8 or not tok.isascii() or not tok.isprintable()):
        fail("--token: give auto, none, or at least 8 printable ASCII characters")
    return Access(tuple(o.rstrip("/") for o in allow_origin or ()), tok, max_viewers).check()


@contextmanager
def _signals(stop):
    """SIGTERM and a first Ctrl-C end the loop cleanly (summary printed, files complete); a
    second Ctrl-C interrupts at once."""

    def on_term(signum, frame) -> None:
        stop.set("terminated")

    def on_int(signum, frame) -> None:
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set("interrupted")

    try:
        old = {s: signal.signal(s, h) for s, h in ((signal.SIGTERM, on_term), (signal.SIGINT, on_int))}
    except ValueError:  # not the main thread (an embedding caller): leave signals alone
        old = {}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  fuseflow live /tmp/studio --serve 8080 --loop                 # replay a recording; open http://127.0.0.1:8080/
  fuseflow live realsense --calib calib.json --serve 8080 --crop auto
  fuseflow live /tmp/studio --record /tmp/live-clouds --num-frames 30 --preset default
  fuseflow live /tmp/studio --serve 0.0.0.0:8080 --hold     # LAN viewers: open the printed address (token)
  fuseflow live --ray auto --nodes 3 --calib calib.json --serve 8080   # cameras of 3 capture nodes (fuseflow node)
"""
