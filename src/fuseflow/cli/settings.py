"""The ``NAME=VALUE`` form of a FUSE setting (``--set`` of `fuse` and `run`): ``parse_settings``
turns the strings into ``FuseConfig.replace`` keyword arguments, ``fuse_config`` applies them
over a preset. The library takes configs and mappings, never these strings."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from fuseflow.errors import ValidationError
from fuseflow.fuse import FuseConfig
from fuseflow.fuse.presets import preset_config

__all__ = ["fuse_config", "parse_settings"]


def parse_settings(assignments: Iterable[str]) -> dict[str, Any]:
    """``cfg.replace`` keyword arguments from ``NAME=VALUE`` strings (the CLI's ``--set``): NAME is
    a setting of ``FuseConfig().describe()`` (``rps.k_max``, ``pixel_stride``); VALUE is read as the
    setting's type (bool: true/false/1/0/on/off; noise_sigma: a,b,z0; target_points: none or an int)."""
    known = FuseConfig().describe()
    out: dict[str, Any] = {}
    for text in assignments:
        name, sep, raw = text.partition("=")
        name, raw = name.strip(), raw.strip()
        if not sep or name not in known:
            raise ValidationError(f"--set {text!r}: expected NAME=VALUE with NAME one of {', '.join(known)}")
        value = _parse_value(name, raw, known[name])
        stage, dot, field_name = name.partition(".")
        if dot:
            out.setdefault(stage, {})[field_name] = value
        else:
            out[name] = value
    return out


def _parse_value(name: str, raw: str, default: Any) -> Any:
    """``raw`` as the type of ``default`` (the setting's default value)."""
    low = raw.lower()
    try:
        if isinstance(default, bool):
            if low not in ("true", "false", "1", "0", "on", "off", "yes", "no"):
                raise ValueError(raw)
            return low in ("true", "1", "on", "yes")
        if name == "target_points":
            return None if low == "none" else int(raw)
        if isinstance(default, tuple):
            return tuple(float(v) for v in raw.split(","))
        if isinstance(default, int):
            return int(raw)
        if isinstance(default, float):
            return float(raw)
        return raw
    except ValueError:
        raise ValidationError(f"--set {name}={raw}: expected a value like {default!r}") from None


def fuse_config(preset: str, points: int | None = None, settings: Iterable[str] = ()) -> FuseConfig:
    """--preset, --points and --set as one FuseConfig (``presets.preset_config`` over
    ``parse_settings``); ValidationError for an unknown preset or a bad setting."""
    return preset_config(preset, points, parse_settings(settings))
