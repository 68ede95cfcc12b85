"""Models shipped in the package: ``radar_odom/models/<name>.onnx`` (package data).

    radar_odom.pretrained_names()      # e.g. ["cart-0.4", "cart-0.8"]
    radar_odom.pretrained("cart-0.4")  # path of that ONNX file, for RadarOdometer
"""
from __future__ import annotations

import re
from pathlib import Path

from .errors import ModelNotFoundError, RadarOdomError

MODELS_DIR = Path(__file__).resolve().parent / "models"
DEFAULT_MODEL = "cart-0.4"  # what `radar-odom demo` and `run` use without --model
# a model name: letters, digits, '.', '_', '-', not starting with '.' (so never a path or '..')
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


class UnknownModelError(RadarOdomError, KeyError):
    """A pretrained model name that is not shipped (a KeyError that reads well when printed)."""

    def __str__(self) -> str:  # KeyError would print the message in quotes
        return str(self.args[0]) if self.args else ""


def pretrained_names(models_dir: Path | None = None) -> list[str]:
    """Names of the shipped ONNX models, sorted (empty when none are installed)."""
    d = Path(models_dir) if models_dir else MODELS_DIR
    return sorted(p.stem for p in d.glob("*.onnx")) if d.is_dir() else []


def pretrained(name: str, models_dir: Path | None = None) -> str:
    """Path (str) of the shipped model ``name``; `UnknownModelError` (a KeyError) lists the names.

    ``name`` is a name, never a path: anything but letters, digits, ``.``, ``_`` and ``-``
    (a path separator, ``..``, a leading dot) is refused, so no file outside the package's
    models folder can be reached through it.
    """
    d = Path(models_dir) if models_dir else MODELS_DIR
    if not isinstance(name, str) or not _NAME.fullmatch(name) or ".." in name:
        names = pretrained_names(d)
        shipped = ", ".join(names) if names else "none (this installation ships no models)"
        raise UnknownModelError(
            f"{name!r} is not a model name: pretrained() takes the name of a shipped model "
            f"({shipped}), not a path; give a path to RadarOdometer directly to load another file"
        )
    path = d / f"{name}.onnx"
    if not path.is_file():
        names = pretrained_names(d)
        shipped = ", ".join(names) if names else "none (this installation ships no models)"
        raise UnknownModelError(
            f"no pretrained model {name!r}; shipped models: {shipped}. "
            "Pass a path to an .onnx file exported with `radar-odom export` instead."
        )
    return str(path)


def resolve_model(spec: str) -> str:
    """A model argument as users give it: an existing file path, or a shipped model's name."""
    p = Path(spec)
    if p.suffix == ".onnx" or p.exists():
        if not p.is_file():
            raise ModelNotFoundError(f"{spec}: no such model file")
        return str(p)
    return pretrained(spec)


def default_model_name() -> str:
    """``cart-0.4`` if shipped, else the first shipped model; `RadarOdomError` if none is."""
    names = pretrained_names()
    if not names:
        raise RadarOdomError(
            "this installation ships no pretrained models (radar_odom/models/*.onnx is empty); "
            "pass --model path/to/model.onnx exported with `radar-odom export`"
        )
    return DEFAULT_MODEL if DEFAULT_MODEL in names else names[0]


def shipped_export(name: str) -> dict | None:
    """How the shipped model ``name`` was exported, from its ONNX metadata: ``{"search":
    "exhaustive" | "fast" | "decoupled", "form", "settings": the search's settings (dict) or
    None}``; None when no model of that name is shipped."""
    import json

    import onnxruntime as ort

    if name not in pretrained_names():
        return None
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL  # metadata only: cheap
    meta = ort.InferenceSession(pretrained(name), so, providers=["CPUExecutionProvider"]).get_modelmeta()
    meta = dict(meta.custom_metadata_map)
    search = json.loads(meta.get("radar_odom.search", "null"))
    kind = (search or {}).get("kind")
    names = {None: "exhaustive", "coarse_to_fine": "fast", "decoupled": "decoupled"}
    if kind not in names:
        return None  # a search this version does not know: export as asked
    settings = None if search is None else {k: v for k, v in search.items() if k not in ("kind", "band_rotations")}
    return {"search": names[kind], "form": meta.get("radar_odom.form", "stream"), "settings": settings}
