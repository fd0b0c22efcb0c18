"""`fuseflow node SOURCE --ray HOST:PORT`: this machine's cameras as a capture node of a Ray
cluster, for `fuseflow live --ray` on the fusing host."""

from __future__ import annotations

import signal

import typer

from fuseflow.cli.app import fail, say, warn


def command(
    source: list[str] = typer.Argument(
        ..., help="realsense[:SERIAL,...] | orbbec[:SERIAL,...] | a recording directory (replayed) | .bag/.mkv files."
    ),
    ray: str = typer.Option(..., "--ray", help="HOST:PORT of the Ray head (ray start --head prints it), or auto."),
    name: str = typer.Option(None, "--name", help="This node's name in the cluster (default: the host name)."),
    cameras: str = typer.Option(None, "--cameras", help="CAM,CAM: ship only these cameras of SOURCE."),
    color: str = typer.Option(
        "jpeg",
        "--color",
        help="Colour coder of frames that cross a network: jpeg (lossy) or png (lossless). "
        "A fusing host on this machine gets raw frames (fuseflow live --frame-codec).",
    ),
    depth: str = typer.Option(
        "lz4", "--depth", help="Lossless depth coder of frames that cross a network: lz4 (fast) or png (smaller)."
    ),
    quality: int = typer.Option(90, "--quality", help="JPEG quality 1..100."),
    rate: float = typer.Option(None, "--rate", help="Replay: frames per second (default: the recording's timestamps)."),
    clock_offset_ms: float = typer.Option(
        0.0, "--clock-offset-ms", hidden=True, help="Tests: add this to the node's clock."
    ),
) -> None:
    """Read this machine's cameras and ship their frames to `fuseflow live --ray` through Ray.

    Start the cluster first (ray start --head on the fusing host, ray start --address HEAD:6379
    here), then: fuseflow node realsense --ray HEAD:6379. A replayed recording loops, paced by
    the wall clock, so that nodes replaying other cameras of it stay in step. Ctrl-C stops.
    """
    from fuseflow.live.sources import ReplayOptions
    from fuseflow.live.sources.frame_codec import ViewCodec
    from fuseflow.live.sources.node import NodeOptions, start_node

    if rate is not None and not rate > 0:
        fail(f"--rate must be a positive number of frames per second, got {rate}")
    if color not in ("jpeg", "png"):
        fail(f"--color must be jpeg or png, got {color!r}")
    if depth not in ("lz4", "png"):
        fail(f"--depth must be lz4 or png, got {depth!r}")
    codec = ViewCodec(color=color, quality=quality, depth=depth).check()
    ids = tuple(c.strip() for c in cameras.split(",") if c.strip()) if cameras else None
    if cameras is not None and not ids:
        fail("--cameras expects camera ids separated by commas, e.g. cam00,cam01")
    options = NodeOptions(name=name, cameras=ids, codec=codec, clock_offset_s=clock_offset_ms / 1e3,
                          replay=ReplayOptions(rate=rate, loop=True, preload=True, aligned=True))  # fmt: skip
    handle, joined = start_node(source, options, ray)
    _serve(handle, joined)


def _serve(handle, joined: bool) -> None:
    """Report, then wait for Ctrl-C / SIGTERM or the node's source to fail; stop the actor."""
    import ray

    from fuseflow.live import StopRequest

    stop = StopRequest()  # a signal handler may set it while this thread waits on it
    info = ray.get(handle.info.remote())
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    say(
        f"node {info['name']}: {info['description']}; shipping {', '.join(info['rig'].ids)} to the fusing host (Ctrl-C stops)"
    )
    error = None
    try:
        while not stop.wait(1.0):
            try:
                stats = ray.get(handle.stats.remote(), timeout=10)
            except (ray.exceptions.RayError, ray.exceptions.GetTimeoutError) as exc:
                error = (
                    f"the node's actor is gone ({type(exc).__name__}): the Ray cluster or this machine's raylet stopped"
                )
                break
            if stats["error"] or stats["ended"]:
                error = stats["error"] or "the source ended"
                break
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        try:
            ray.get(handle.stop.remote(), timeout=5)
            ray.kill(handle)
        except Exception:  # noqa: BLE001 - already gone
            pass
        if joined:
            ray.shutdown()
    if error:
        warn(error, stderr=True)
        raise typer.Exit(1)
    say(f"node {info['name']} stopped")


#: ``--help`` examples (click keeps a paragraph after "\\b" as written).
EXAMPLES = """\b
Examples:
  ray start --address HEAD:6379 && fuseflow node realsense --ray HEAD:6379
  fuseflow node orbbec --ray HEAD:6379 --name rack2
  fuseflow node /data/studio --cameras cam00,cam01,cam02 --ray auto   # replay some cameras of a recording
"""
