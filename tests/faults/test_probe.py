"""The fault-injection probe: corrupt inputs that used to be fused silently wrong,
wrong calibrations the run must flag, unusable outputs and environments that used to end in a
traceback. Each test breaks one thing, runs the CLI (or the API) as a user would, and checks the
exit code, that no traceback is printed, and the words that name the fault. docs/reliability.md
lists each case."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

CAMS = ("cam00", "cam01", "cam02")


def copy_rec(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


# --------------------------------------------------------------------- silently wrong inputs


def test_jpeg_corrupt_in_the_middle_is_refused(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    png = rec / "cam01" / "color" / "000000.png"
    ok, buf = cv2.imencode(".jpg", cv2.imread(str(png)))
    data = bytearray(buf.tobytes())
    n = len(data)
    data[n // 2 : n // 2 + 200] = np.random.default_rng(0).bytes(200)  # the end marker stays
    assert data[-2:] == b"\xff\xd9"
    png.unlink()
    (rec / "cam01" / "color" / "000000.jpg").write_bytes(bytes(data))
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 2, "cam01/color/000000.jpg", "corrupt JPEG data")
    expect(invoke("info", rec, "--check"), 1, "cam01/color/000000.jpg", "corrupt JPEG")


def test_intact_jpeg_still_reads(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    png = rec / "cam01" / "color" / "000000.png"
    cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png)))
    png.unlink()
    expect(invoke("info", rec, "--check"), 0, "every colour and depth file decodes")


def test_three_channel_16_bit_depth_is_not_depth(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    p = rec / "cam01" / "depth" / "000000.png"
    d = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), np.dstack([d, d // 2, d // 3]))  # a 16-bit RGB PNG
    expect(invoke("fuse", rec, "--out", tmp_path / "o"), 2, "cam01/depth/000000.png", "one channel", "not depth")


# ------------------------------------------------------------------- wrong calibrations, run


def _calib(rec: Path, path: Path, edit) -> Path:
    from fuseflow.io import open_recording, write_calibration
    from fuseflow.types import Calibration

    rig = open_recording(rec).rig
    T = edit({c.id: np.array(c.T_cam_world) for c in rig})
    write_calibration(path, Calibration(T, {"source": "test"}), rig=rig)
    return path


def _summary_warnings(out: Path) -> str:
    return " ".join(json.loads((out / "summary.json").read_text())["warnings"])


def test_right_calibration_gives_no_agreement_warning(small_rec, tmp_path, invoke, expect):
    calib = _calib(small_rec, tmp_path / "c.json", lambda T: T)
    expect(invoke("run", small_rec, "--out", tmp_path / "o", "--calib", calib), 0)
    assert "disagrees" not in _summary_warnings(tmp_path / "o")
    rows = [json.loads(x) for x in (tmp_path / "o" / "frames.jsonl").read_text().splitlines()]
    assert min(a for r in rows for a in r["agreement"].values()) > 0.6


def test_permuted_extrinsics_are_flagged(tmp_path, invoke, expect, make_recording):
    # six cameras in reverse order (on a symmetric 3-camera ring a swap is nearly a reflection)
    rec = make_recording(tmp_path / "rec6", cameras=6, frames=1)
    calib = _calib(rec, tmp_path / "c.json", lambda T: dict(zip(T, list(T.values())[::-1])))
    res = invoke("run", rec, "--out", tmp_path / "o", "--calib", calib)
    expect(res, 0, "disagrees with their neighbours", "cam01", "cam04", "does not fit this recording")
    assert "does not fit this recording" in _summary_warnings(tmp_path / "o")


def _measured(rec: Path) -> dict:
    """What a calibration's report records: each camera's depth agreement under the true extrinsics."""
    from fuseflow.geometry.agreement import depth_agreement
    from fuseflow.io import open_recording

    r = open_recording(rec)
    return depth_agreement(r[0], r.rig, {c.id: np.array(c.T_cam_world) for c in r.rig})


def _swap_with_report(rec: Path, path: Path, swap: bool) -> Path:
    """calib.json with the report of a calibration of ``rec`` (its depth agreement), and cam01 and
    cam02's extrinsics swapped afterwards when ``swap`` (a hand edit, or two cables exchanged)."""
    from fuseflow.io import open_recording, write_calibration
    from fuseflow.types import Calibration

    rig = open_recording(rec).rig
    T = {c.id: np.array(c.T_cam_world) for c in rig}
    if swap:
        T["cam01"], T["cam02"] = T["cam02"], T["cam01"]
    write_calibration(path, Calibration(T, {"depth_agreement": _measured(rec)}), rig=rig)
    return path


@pytest.mark.parametrize("swap", [False, True])
def test_swap_on_a_symmetric_ring_is_flagged_against_the_calibrations_agreement(small_rec, tmp_path, invoke, expect,
                                                                                swap):  # fmt: skip
    """On a 3-camera ring a swap is nearly a reflection: agreement stays above LOW_AGREEMENT, but
    falls well below what the calibration itself measured."""
    calib = _swap_with_report(small_rec, tmp_path / "c.json", swap)
    res = invoke("run", small_rec, "--out", tmp_path / "o", "--calib", calib)
    words = "less than when they were calibrated"
    if swap:
        expect(res, 0, words, "cam01", "cam02", "may not fit this recording")
        assert words in _summary_warnings(tmp_path / "o")
    else:
        expect(res, 0)
        assert words not in _summary_warnings(tmp_path / "o")


def test_calibration_in_millimetres_is_refused(small_rec, tmp_path, invoke, expect):
    def mm(T):
        for v in T.values():
            v[:3, 3] *= 1000.0
        return T

    calib = _calib(small_rec, tmp_path / "c.json", mm)
    expect(invoke("run", small_rec, "--out", tmp_path / "o", "--calib", calib), 2, "millimetres")
    assert not list((tmp_path / "o").glob("clouds/*.ply"))


def test_depth_range_that_excludes_every_pixel_is_refused(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    doc = json.loads((rec / "rig.json").read_text())
    for cam in doc["cameras"]:
        cam["depth_range"] = [20.0, 30.0]
    (rec / "rig.json").write_text(json.dumps(doc))
    expect(invoke("run", rec, "--out", tmp_path / "o", "--use-rig"), 2, "depth_range", "every cloud would be empty")


def test_run_passes_fuse_warnings_on(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    doc = json.loads((rec / "rig.json").read_text())
    doc["cameras"][1]["depth_range"] = [20.0, 30.0]  # cam01 alone loses every pixel
    (rec / "rig.json").write_text(json.dumps(doc))
    res = invoke("run", rec, "--out", tmp_path / "o", "--use-rig")
    expect(res, 0, "no depth inside their depth_range", "cam01")
    assert " ".join(res.output.split()).count("no depth inside their depth_range") == 1  # once, with frame numbers
    assert "cam01" in _summary_warnings(tmp_path / "o")


# ------------------------------------------------------------------------------ outputs


def test_two_runs_into_one_out_at_once(small_rec, tmp_path, invoke, expect):
    import subprocess
    import sys

    out = tmp_path / "o"
    out.mkdir()
    holder = subprocess.Popen(  # another process holding OUT's lock, as a running `run` does
        [sys.executable, "-c", "import fcntl,os,sys,time; fd=os.open(sys.argv[1], os.O_RDONLY); "
         "fcntl.flock(fd, fcntl.LOCK_EX); print('held', flush=True); time.sleep(60)", str(out)],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        expect(invoke("run", small_rec, "--out", out, "--use-rig"), 2, "another fuseflow process")
        expect(invoke("fuse", small_rec, "--out", out), 2, "another fuseflow process")
        assert not (out / "frames.jsonl").exists()
    finally:
        holder.kill()
        holder.wait()
    expect(invoke("run", small_rec, "--out", out, "--use-rig"), 0, "2 fused now")  # the lock died with it
    assert [p.name for p in out.iterdir() if p.name.startswith(".")] == []  # no lock file left behind


def test_recording_changed_after_a_run_is_not_resumed(small_rec, tmp_path, invoke, expect):
    import os

    rec = copy_rec(small_rec, tmp_path / "rec")
    out = tmp_path / "o"
    expect(invoke("run", rec, "--out", out, "--use-rig"), 0)
    p = rec / "cam01" / "depth" / "000001.png"
    d = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(p), (d * 0.9).astype(np.uint16))  # new content, same file name
    st = os.stat(p)
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    expect(invoke("run", rec, "--out", out, "--use-rig"), 2, "recording content", "modification time", "--force")
    expect(invoke("run", rec, "--out", out, "--use-rig", "--force"), 0, "2 fused now")


class _FullDisk:
    """A file whose writes fail with ENOSPC once ``budget`` bytes were written (a full disk)."""

    def __init__(self, f, budget: int):
        self.f, self.budget = f, budget

    def write(self, b):
        import errno

        if self.budget - len(b) < 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.budget -= len(b)
        return self.f.write(b)

    def __enter__(self):
        return self

    def __exit__(self, *a):
        self.f.close()


def _fill_disk(monkeypatch, budget: int = 300) -> None:
    import builtins

    from fuseflow.io import files

    monkeypatch.setattr(files, "open", lambda p, mode="r": _FullDisk(builtins.open(p, mode), budget), raising=False)


@pytest.mark.parametrize("command", ["run", "fuse"])
def test_full_disk_under_out(small_rec, tmp_path, monkeypatch, command, invoke, expect):
    _fill_disk(monkeypatch)
    args = ("--use-rig",) if command == "run" else ()
    expect(invoke(command, small_rec, "--out", tmp_path / "o", *args), 2, "no space left on the device", "MB free")
    assert not list(tmp_path.rglob("*.tmp"))


def test_full_disk_for_a_calibration_file(small_rec, tmp_path, monkeypatch):
    # calibrate writes calib.json through the same atomic write (GMAC itself is not needed here)
    from fuseflow.errors import OutputError
    from fuseflow.io import open_recording, write_calibration
    from fuseflow.types import Calibration

    rig = open_recording(small_rec).rig
    _fill_disk(monkeypatch, budget=10)
    with pytest.raises(OutputError, match="no space left on the device"):
        write_calibration(tmp_path / "c.json", Calibration({c.id: c.T_cam_world for c in rig}, {}), rig=rig)
    assert not list(tmp_path.iterdir())


def _cli(*args, env=None, stdout=None):
    import os
    import subprocess
    import sys

    src = str(Path(__file__).resolve().parents[2] / "src")
    e = {**os.environ, "PYTHONPATH": src, **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", "fuseflow", *map(str, args)], env=e, stdout=stdout or subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, timeout=120,
    )  # fmt: skip


@pytest.mark.parametrize("args", [("info", "REC"), ("--help",)])
def test_stdout_on_a_full_device(small_rec, args):
    with open("/dev/full", "w") as full:
        res = _cli(*[small_rec if a == "REC" else a for a in args], stdout=full)
    assert res.returncode == 2, res.stderr
    assert "Traceback" not in res.stderr and "Exception ignored" not in res.stderr, res.stderr
    assert "no space left on device" in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_native_log_that_cannot_be_written_stays_out_of_errors(tmp_path):
    (tmp_path / "fuseflow-native.log").mkdir()  # not writable as a file
    res = _cli("fuse", tmp_path / "nothing", "--out", tmp_path / "o", env={"TMPDIR": str(tmp_path)})
    assert res.returncode == 2, res.stderr
    assert "Error" not in res.stderr.replace("error:", "") and "Traceback" not in res.stderr, res.stderr
    assert len(res.stderr.strip().splitlines()) == 1, res.stderr


# ------------------------------------------------------------------------- tracebacks


def test_calib_frame_beyond_the_recording(small_rec, tmp_path, invoke, expect):
    expect(invoke("run", small_rec, "--out", tmp_path / "o", "--calib-frame", 7), 2, "--calib-frame", "2 frames")


def test_ray_address_with_no_cluster(small_rec, tmp_path, invoke, expect):
    import socket

    with socket.socket() as s:  # a free port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    res = invoke("run", small_rec, "--out", tmp_path / "o", "--use-rig", "--ray", "--ray-address", f"127.0.0.1:{port}")
    expect(res, 2, f"--ray-address 127.0.0.1:{port}", "no Ray cluster answers", "ray start --head")


def test_tum_list_line_without_a_file_name(tmp_path, invoke, expect):
    rec = tmp_path / "tum"
    rec.mkdir()
    (rec / "rgb.txt").write_text("# timestamp filename\n1.0 rgb/1.png\n2.0\n")
    (rec / "depth.txt").write_text("1.0 depth/1.png\n")
    expect(invoke("info", rec), 2, "rgb.txt:3", "no file name")


@pytest.mark.parametrize("name", ["rig.json", "calib.json"])
def test_deeply_nested_json(small_rec, tmp_path, name, invoke, expect):
    bad = "[" * 100_000 + "]" * 100_000
    if name == "rig.json":
        rec = copy_rec(small_rec, tmp_path / "rec")
        (rec / "rig.json").write_text(bad)
        expect(invoke("info", rec), 2, "rig.json", "nested too deeply")
    else:
        (tmp_path / "calib.json").write_text(bad)
        expect(invoke("fuse", small_rec, "--calib", tmp_path / "calib.json", "--out", tmp_path / "o"), 2, "nested")


@pytest.mark.parametrize("where", ["a file", "under a file"])
def test_view_save_png_dir_unusable(small_rec, tmp_path, where, invoke, expect):
    run_dir = tmp_path / "run"
    expect(invoke("run", small_rec, "--out", run_dir, "--use-rig"), 0)
    (tmp_path / "f").write_text("x")
    target = tmp_path / "f" if where == "a file" else tmp_path / "f" / "pngs"
    expect(invoke("view", run_dir, "--save-png", target), 2, "is a file")


def test_view_save_png_dir_not_writable(small_rec, tmp_path, monkeypatch, invoke, expect):
    import errno
    import tempfile

    run_dir = tmp_path / "run"
    expect(invoke("run", small_rec, "--out", run_dir, "--use-rig"), 0)

    def refuse(*a, **k):  # the tests run as root, where chmod does not stop writes
        raise OSError(errno.EACCES, "refused")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    expect(invoke("view", run_dir, "--save-png", tmp_path / "pngs"), 2, "no permission")


def test_view_frames_beyond_the_run(small_rec, tmp_path, invoke, expect):
    run_dir = tmp_path / "run"
    expect(invoke("run", small_rec, "--out", run_dir, "--use-rig"), 0)
    expect(
        invoke("view", run_dir, "--frames", "7:9", "--save-png", tmp_path / "p"),
        2,
        "7:9",
        "selects no frame",
        "2 frames",
    )


def test_view_with_no_display_says_what_to_do(small_rec, tmp_path, monkeypatch, invoke, expect):
    import time

    from fuseflow.cli import view

    run_dir = tmp_path / "run"
    expect(invoke("run", small_rec, "--out", run_dir, "--use-rig"), 0)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(view, "VIEWER_PORT", _free_port())
    t0 = time.perf_counter()
    expect(invoke("view", run_dir), 2, "no display", "--rrd", "--save-png")
    assert time.perf_counter() - t0 < 5
    expect(invoke("view", run_dir, "--rrd", tmp_path / "run.rrd"), 0, "wrote")
    assert (tmp_path / "run.rrd").stat().st_size > 0


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_echoed_input_is_never_an_emoji(small_rec, tmp_path, invoke, expect):
    res = invoke("run", small_rec, "--out", tmp_path / "o", "--device", "cuda:smile:")
    expect(res, 2, "cuda:smile:")
    assert "\U0001f604" not in res.output


# ----------------------------------------------------------------- numba's kernel cache

_KERNEL = """
import importlib.util, os
spec = importlib.util.spec_from_file_location("numba_cache", os.environ["NUMBA_CACHE_MODULE"])
numba_cache = importlib.util.module_from_spec(spec)  # without fuseflow's torch import: seconds faster
spec.loader.exec_module(numba_cache)
numba_cache.use_usable_cache(__file__)
from numba import njit
@njit(cache=True)
def f(x):
    return x + 1
"""


def _kernel_run(pkg: Path, env: dict, drop=()):
    """Import a one-kernel module with numba caching from a fresh interpreter; (rc, stdout, stderr)."""
    import os
    import subprocess
    import sys

    module = str(Path(__file__).resolve().parents[2] / "src" / "fuseflow" / "io" / "numba_cache.py")
    e = {k: v for k, v in {**os.environ, "NUMBA_CACHE_MODULE": module, **env}.items() if k not in drop}
    res = subprocess.run(
        [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(pkg)!r}); import k; print(k.f(1))"],
        env=e, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    return res.returncode, res.stdout.strip(), res.stderr


def _kernel_pkg(tmp_path: Path) -> Path:
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "k.py").write_text(_KERNEL)
    return pkg


NUMBA_CACHE_FAULTS = {
    # name: (set up, env, environment variables removed)
    "NUMBA_CACHE_DIR is a file": (
        lambda t, p: (t / "f").write_text("x"),
        lambda t: {"NUMBA_CACHE_DIR": str(t / "f")},
        (),
    ),
    "NUMBA_CACHE_DIR under a file": (
        lambda t, p: (t / "f").write_text("x"),
        lambda t: {"NUMBA_CACHE_DIR": str(t / "f" / "c")},
        (),
    ),
    # a read-only install: __pycache__ cannot be created (a file in its place; chmod does not stop root)
    "package __pycache__ unwritable, HOME unset": (
        lambda t, p: (p / "__pycache__").write_text("x"),
        lambda t: {"TMPDIR": str(t)},
        ("HOME", "NUMBA_CACHE_DIR"),
    ),
}


@pytest.mark.parametrize("kind", list(NUMBA_CACHE_FAULTS))
def test_numba_cache_that_cannot_be_written(tmp_path, kind):
    setup, env, drop = NUMBA_CACHE_FAULTS[kind]
    pkg = _kernel_pkg(tmp_path)
    setup(tmp_path, pkg)
    rc, out, err = _kernel_run(pkg, env(tmp_path), drop)
    assert (rc, out) == (0, "2"), err
    assert "Traceback" not in err and err.count("NumbaCacheWarning") == 1, err


@pytest.mark.parametrize("damage", ["garbage index (.nbi)", "data cut to 100 bytes (.nbc)"])
def test_numba_cache_file_damaged(tmp_path, damage):
    pkg = _kernel_pkg(tmp_path)
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    assert _kernel_run(pkg, env)[:2] == (0, "2")
    ext = ".nbi" if "nbi" in damage else ".nbc"
    files = list((tmp_path / "cache").rglob(f"*{ext}"))
    assert files
    for f in files:
        f.write_bytes(b"garbage\n" if ext == ".nbi" else f.read_bytes()[:100])
    rc, out, err = _kernel_run(pkg, env)
    assert (rc, out) == (0, "2") and "Traceback" not in err, err
    assert _kernel_run(pkg, env)[:2] == (0, "2")  # rewritten: the next start loads it again


# ------------------------------------------------------------------ reruns and numbers


def test_rerun_of_a_finished_run_keeps_its_numbers(small_rec, tmp_path, invoke, expect):
    rec = copy_rec(small_rec, tmp_path / "rec")
    doc = json.loads((rec / "rig.json").read_text())
    doc["cameras"][1]["depth_range"] = [20.0, 30.0]  # a warning the summary must keep
    (rec / "rig.json").write_text(json.dumps(doc))
    out = tmp_path / "o"
    res = invoke("run", rec, "--out", out, "--use-rig")
    expect(res, 0, "checking inputs, then fusing 2 frames", "ms per frame warm", "first frame", "output", "MB in")
    before = (out / "summary.json").read_text()
    assert json.loads(before)["fps"] > 0 and json.loads(before)["warm_ms_per_frame"] > 0
    expect(invoke("run", rec, "--out", out, "--use-rig"), 0, "nothing to do", "cam01")
    assert (out / "summary.json").read_text() == before


def test_truncated_mkv_is_named(tmp_path, invoke, expect):
    import sys

    pytest.importorskip("av")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
    import test_azure_kinect as ak

    a, *_ = ak._recording(tmp_path, "a", "A", t0_us=3_000_000)
    b, *_ = ak._recording(tmp_path, "b", "B", t0_us=3_000_160)
    b.write_bytes(b.read_bytes()[: int(b.stat().st_size * 0.6)])  # cut during the last frames
    expect(
        invoke("convert", a, b, tmp_path / "rec"),
        0,
        "2 dropped views",
        "B: 2 views: 2 at the end",
        "b.mkv",
        "truncated",
    )


def test_convert_interrupted_says_force(small_rec, tmp_path, monkeypatch, invoke, expect):
    import fuseflow.io.convert as conv

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(conv, "convert", interrupted)
    expect(invoke("convert", small_rec, tmp_path / "rec"), 130, "interrupted", "--force")


def test_full_tmpdir_during_calibrate(small_rec, tmp_path, monkeypatch, invoke, expect):
    real = cv2.imwrite

    def full(path, img, *a):  # OpenCV says only False when the disk is full
        return False if "fuseflow-colmap-" in str(path) else real(path, img, *a)

    monkeypatch.setattr(cv2, "imwrite", full)
    res = invoke("calibrate", small_rec, "--out", tmp_path / "c.json", "--backbone", "colmap")
    expect(res, 2, "COLMAP's workspace", "MB free", "TMPDIR")
    assert not (tmp_path / "c.json").exists()
