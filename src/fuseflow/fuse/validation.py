"""Checks of FuseConfig's fields (``from fuseflow.fuse import validation as check``): each failure is a ValidationError naming the setting
(``FuseConfig.rps.k_max``), what it expects and what it got."""

from __future__ import annotations

import math

from fuseflow.errors import ValidationError

__all__ = ["fail", "numbers", "ints", "bools", "noise_sigma", "target_points"]


def fail(path: str, value: object, want: str) -> None:
    raise ValidationError(f"FuseConfig.{path}: expected {want}, got {value!r}")


def numbers(cfg: object, stage: str, names: tuple[str, ...], positive: bool) -> None:
    """Each field of ``names`` is a finite number > 0 (``positive``) or >= 0."""
    for name in names:
        v = getattr(cfg, name)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 3.4e38  # float32 kernels
        if not ok or v < 0 or (positive and v == 0):
            fail(f"{stage}{name}", v, "a finite float32 > 0" if positive else "a finite float32 >= 0")


def ints(cfg: object, stage: str, bounds: tuple[tuple[str, int, int, str], ...]) -> None:
    """Each (name, lo, hi, note) field is an integer in lo..hi (a bool is not one)."""
    for name, lo, hi, note in bounds:
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
            fail(f"{stage}{name}", v, f"an integer in {lo}..{hi}{note}")


def bools(cfg: object, stage: str, names: tuple[str, ...]) -> None:
    for name in names:
        if not isinstance(getattr(cfg, name), bool):
            fail(f"{stage}{name}", getattr(cfg, name), "a bool")


def noise_sigma(ns: object) -> None:
    """(a, b, z0): finite numbers with a > 0 and b >= 0."""
    if (
        not isinstance(ns, tuple)
        or len(ns) != 3
        or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in ns)
        or not ns[0] > 0
        or ns[1] < 0
    ):
        fail("noise_sigma", ns, "a tuple (a, b, z0) of finite numbers with a > 0, b >= 0")


def target_points(tp: object) -> None:
    """None or an integer >= 1 (a bool is not one)."""
    if tp is not None and (not isinstance(tp, int) or isinstance(tp, bool) or tp < 1):
        fail("target_points", tp, "None or an integer >= 1")
