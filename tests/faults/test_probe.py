"""The fault-injection probe of issue 31: corrupt inputs that used to be fused silently wrong,
wrong calibrations the run must flag, unusable outputs and environments that used to end in a
traceback. Each test breaks one thing, runs the CLI (or the API) as a user would, and checks the
exit code, that no traceback is printed, and the words that name the fault. docs/reliability.md
lists each case."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

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
