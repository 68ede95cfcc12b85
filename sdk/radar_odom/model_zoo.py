"""Models shipped in the package (``radar_odom/models/<name>.onnx``, package data) and a user's own,
each listed with its SHA-256 in a registry (`radar_odom.model_registry`; ``radar-odom models`` prints it).

    radar_odom.pretrained_names()      # e.g. ["cart-0.4", "cart-0.8"], then the local models
    radar_odom.pretrained("cart-0.4")  # path of that ONNX file, its digest checked, for RadarOdometer

A user's own models live in ``$RADAR_ODOM_HOME/models`` (default ``~/.radar-odom/models``), added with
``radar-odom models --add NAME FILE.onnx``; a shipped name comes first, so a local model never shadows one.
"""
from __future__ import annotations

from pathlib import Path

from . import model_registry
from .errors import ModelNotFoundError, RadarOdomError
from .model_registry import NAME as _NAME  # noqa: F401  (the name pattern; its home is model_registry)
from .model_registry import valid_name

MODELS_DIR = model_registry.SHIPPED_DIR
DEFAULT_MODEL = "cart-0.4"  # what `radar-odom demo` and `run` use without --model


class UnknownModelError(RadarOdomError, KeyError):
    """A pretrained model name that is not shipped (a KeyError that reads well when printed)."""

    def __str__(self) -> str:  # KeyError would print the message in quotes
        return str(self.args[0]) if self.args else ""


def _folders(models_dir) -> list[tuple[Path, str]]:
    """(folder, source) in the order names are looked up: the shipped folder, then the local one; a
    ``models_dir`` given replaces both."""
    if models_dir:
        return [(Path(models_dir), "shipped")]
    return [(Path(MODELS_DIR), "shipped"), (model_registry.local_dir(), "local")]


def _names_in(folder: Path, source: str) -> list[str]:
    """A folder's model names: its registry's, or (a shipped folder without one: an older layout or a
    folder given as ``models_dir``) its ``*.onnx`` files, unchecked. A local folder lists only its registry."""
    reg = model_registry.read_registry(folder, source)
    if reg is not None:
        return sorted(reg)
    if source == "shipped" and folder.is_dir():
        return sorted(p.stem for p in folder.glob("*.onnx"))
    return []


def pretrained_names(models_dir: Path | None = None) -> list[str]:
    """Names `pretrained` accepts, sorted: the shipped models, then the user's own (``$RADAR_ODOM_HOME``) not
    named as a shipped one; empty when none are installed. With ``models_dir``, that folder's only."""
    names: list[str] = []
    for folder, source in _folders(models_dir):
        names += [n for n in _names_in(folder, source) if n not in names]
    return names


def shipped_names() -> list[str]:
    """The shipped models' names only (no local ones), sorted."""
    return _names_in(Path(MODELS_DIR), "shipped")


def registry_entries(models_dir: Path | None = None) -> list[model_registry.Entry]:
    """Every registered model (shipped first, then local), as `pretrained_names` orders them."""
    out, seen = [], set()
    for folder, source in _folders(models_dir):
        for name, entry in sorted((model_registry.read_registry(folder, source) or {}).items()):
            if name not in seen:
                seen.add(name)
                out.append(entry)
    return out


def pretrained(name: str, models_dir: Path | None = None) -> str:
    """Path (str) of the registered model ``name``, its SHA-256 checked against its registry.

    Looked up among the shipped models, then the user's own (``$RADAR_ODOM_HOME/models``). An unknown name is
    an `UnknownModelError` (a KeyError) listing the names; a registered file that is missing a
    `ModelNotFoundError`; one whose digest differs a `radar_odom.errors.ModelDigestError` naming the file, both
    digests and what to do (reinstall). Each file is hashed once per process (`model_registry.file_sha256`).

    ``name`` is a name, never a path: anything but letters, digits, ``.``, ``_`` and ``-``
    (a path separator, ``..``, a leading dot) is refused, so no file outside the registries' folders can be
    reached through it.
    """
    folders = _folders(models_dir)
    if not valid_name(name):
        raise UnknownModelError(
            f"{name!r} is not a model name: pretrained() takes the name of a shipped model "
            f"({_listing(models_dir)}), not a path; give a path to RadarOdometer directly to load another file"
        )
    for folder, source in folders:
        reg = model_registry.read_registry(folder, source)
        if reg is not None:
            if name in reg:
                return model_registry.check_file(reg[name])
        elif source == "shipped" and (folder / f"{name}.onnx").is_file():
            return str(folder / f"{name}.onnx")  # a folder without a registry: nothing to check against
    raise UnknownModelError(
        f"no pretrained model {name!r}; shipped models: {_listing(models_dir)}. "
        "Pass a path to an .onnx file exported with `radar-odom export` instead, or register it by name "
        "with `radar-odom models --add NAME FILE.onnx`."
    )


def _listing(models_dir) -> str:
    """'cart-0.4, cart-0.8' (the shipped names), then '; local models (FOLDER): …' where there are any."""
    (shipped_dir, _), *rest = _folders(models_dir)
    shipped = _names_in(shipped_dir, "shipped")
    text = ", ".join(shipped) if shipped else "none (this installation ships no models)"
    for folder, source in rest:
        local = [n for n in _names_in(folder, source) if n not in shipped]
        if local:
            text += f"; local models ({folder}): {', '.join(local)}"
    return text


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
    names = shipped_names()
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
