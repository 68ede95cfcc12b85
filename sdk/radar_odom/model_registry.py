"""The model registry: every model `radar_odom.pretrained` loads by name, with its SHA-256 and what it is.

Two folders, one file format:

* the shipped models, ``radar_odom/models/registry.json`` beside the files (package data);
* a user's own models, ``$RADAR_ODOM_HOME/models/registry.json`` (``RADAR_ODOM_HOME`` defaults to
  ``~/.radar-odom``), written by ``radar-odom models --add NAME FILE.onnx`` (which copies the file there
  as ``NAME.onnx``) and ``radar-odom models --remove NAME``.

``registry.json``::

    {"format": "radar-odom-registry/1",
     "models": {"NAME": {"file": "NAME.onnx", "sha256": "<64 hex digits>", "size": <bytes>,
                         "grid": "0.4 m × 256 px", "form": "stream", "search": "fast (c4s6b2)",
                         "trained_on": "...", "calibrated_on": "...",
                         "scorecard": {"date": "...", "section": "...", "line": "..."} or null}}}

``file`` (a bare file name in that folder), ``sha256`` and ``size`` are required; the other fields
describe the model (`describe` reads them from the file's ONNX metadata; ``scorecard`` quotes, for a
shipped model, the summary line of the docs/scorecard.md section that judged it, with that section's
heading and date). A hand-written local entry needs only the three required fields.

`check_file` holds a file to its entry: a missing file is a `ModelNotFoundError`, another size or
digest a `ModelDigestError` naming the file, both digests and what to do. Hashing a shipped file
(10–12 MB) took 9–18 ms a call on this 2-core machine (median 14–18 ms under load 6–7; 14–28 ms the first
call in a process), against 300–430 ms for `OnnxModel` to load it. `file_sha256` keeps each digest for the
life of the process, keyed by path, size, mtime, ctime and inode, so a later ``pretrained`` call costs
0.6–0.7 ms (reading registry.json and one ``stat``). A file rewritten in place to the same size within one
tick of the file system's clock, by this same process after it hashed it, would keep its old digest here.

Maintainers: ``python -m radar_odom.model_registry --refresh`` rewrites the shipped registry's
measured fields (digest, size, grid, form, search, training and calibration) from the files, adds an
entry for a new file and drops the entry of a removed one; the ``scorecard`` quotes are kept as written.

This module imports onnxruntime only to read a file's metadata (`describe`), never torch.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

from .errors import ModelDigestError, ModelNotFoundError, RegistryError

FORMAT = "radar-odom-registry/1"
REGISTRY_FILE = "registry.json"
HOME_ENV = "RADAR_ODOM_HOME"
DEFAULT_HOME = "~/.radar-odom"
SHIPPED_DIR = Path(__file__).resolve().parent / "models"
# a model name: letters, digits, '.', '_', '-', not starting with '.' (so never a path or '..')
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")
_HEX64 = re.compile(r"[0-9a-f]{64}")
DESCRIPTION_FIELDS = ("grid", "form", "search", "trained_on", "calibrated_on")

# path -> ((size, mtime_ns, ctime_ns, inode), sha256): one hash per file and process while the file is unchanged
_DIGESTS: dict[str, tuple[tuple[int, int, int, int], str]] = {}


def home() -> Path:
    """``$RADAR_ODOM_HOME``, else ``~/.radar-odom`` (not created here)."""
    return Path(os.environ.get(HOME_ENV) or DEFAULT_HOME).expanduser()


def local_dir() -> Path:
    """The folder of a user's own models: ``<home()>/models``."""
    return home() / "models"


def valid_name(name) -> bool:
    """A model name (letters, digits, ``.``, ``_``, ``-``; not a path, no ``..``)."""
    return isinstance(name, str) and bool(NAME.fullmatch(name)) and ".." not in name


def file_sha256(path) -> str:
    """SHA-256 (hex) of the file, cached for this process while its size, mtime, ctime and inode stay."""
    path = Path(path)
    st = path.stat()
    key, stamp = str(path.resolve()), (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)
    hit = _DIGESTS.get(key)
    if hit is not None and hit[0] == stamp:
        return hit[1]
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    _DIGESTS[key] = (stamp, h.hexdigest())
    return h.hexdigest()


@dataclass(frozen=True)
class Entry:
    """One model of a registry: where its file is, what its digest and size must be, what it is."""

    name: str
    path: Path
    sha256: str
    size: int
    source: str  # "shipped" or "local"
    registry: Path  # the registry.json that lists it
    grid: str = ""
    form: str = ""
    search: str = ""
    trained_on: str = ""
    calibrated_on: str = ""
    scorecard: dict | None = None

    def to_json(self) -> dict:
        """The entry as its registry.json writes it."""
        out = {"file": self.path.name, "sha256": self.sha256, "size": self.size}
        out.update({k: getattr(self, k) for k in DESCRIPTION_FIELDS})
        out["scorecard"] = self.scorecard
        return out


def registry_path(folder) -> Path:
    return Path(folder) / REGISTRY_FILE


def read_registry(folder, source: str) -> dict[str, Entry] | None:
    """The entries of ``folder/registry.json`` by name; None when the folder has no registry file.

    `RegistryError` (naming the file and the entry) for text that is not JSON, another format, or an entry
    without a bare file name, a 64-digit lowercase hex ``sha256`` or a whole ``size``.
    """
    reg = registry_path(folder)
    if not reg.is_file():
        return None
    try:
        data = json.loads(reg.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RegistryError(f"{reg}: not a readable JSON registry ({exc}); {_fix(source, reg)}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT or not isinstance(data.get("models"), dict):
        raise RegistryError(f"{reg}: not a model registry (expected an object with \"format\": {FORMAT!r} and a "
                            f"\"models\" object); {_fix(source, reg)}")
    entries = {}
    for name, e in data["models"].items():
        where = f"{reg}: entry {name!r}"
        if not valid_name(name):
            raise RegistryError(f"{where}: not a model name (letters, digits, '.', '_', '-'); {_fix(source, reg)}")
        if not isinstance(e, dict):
            raise RegistryError(f"{where} is not an object; {_fix(source, reg)}")
        file, digest, size = e.get("file"), e.get("sha256"), e.get("size")
        if not isinstance(file, str) or not file or Path(file).name != file or file.startswith("."):
            raise RegistryError(f"{where}: \"file\" must be a file name in {reg.parent} (no folder), got {file!r}; "
                                f"{_fix(source, reg)}")
        if not isinstance(digest, str) or not _HEX64.fullmatch(digest):
            raise RegistryError(f"{where}: \"sha256\" must be 64 lowercase hex digits, got {digest!r}; "
                                f"{_fix(source, reg)}")
        if not isinstance(size, int) or isinstance(size, bool) or size < 0:
            raise RegistryError(f"{where}: \"size\" must be a whole number of bytes, got {size!r}; {_fix(source, reg)}")
        scorecard = e.get("scorecard")
        entries[name] = Entry(
            name=name, path=reg.parent / file, sha256=digest, size=size, source=source, registry=reg,
            scorecard=scorecard if isinstance(scorecard, dict) else None,
            **{k: str(e.get(k) or "") for k in DESCRIPTION_FIELDS},
        )
    return entries


def _fix(source: str, reg: Path) -> str:
    if source == "shipped":
        return "the installation is damaged: reinstall radar-odom (pip install --force-reinstall radar-odom)"
    return ("correct it (the format: radar-odom models --help) or remove it and add your models again with "
            "radar-odom models --add")


def _remedy(entry: Entry) -> str:
    if entry.source == "shipped":
        return ("reinstall radar-odom (pip install --force-reinstall --no-deps radar-odom; in a git checkout: "
                f"git checkout -- {entry.path.name} in {entry.path.parent})")
    return (f"add the model again from the file you exported: radar-odom models --add {entry.name} FILE.onnx "
            "--force (or radar-odom models --remove " + entry.name + ")")


def check_file(entry: Entry) -> str:
    """The entry's file path (str) once its size and SHA-256 match the registry's.

    `ModelNotFoundError` when the file is missing; `ModelDigestError` (naming the file, the expected and the
    found digest and what to do) when it differs.
    """
    if not entry.path.is_file():
        raise ModelNotFoundError(
            f"{entry.path}: the {entry.source} model {entry.name!r} is listed in {entry.registry} but its file is "
            f"missing; {_remedy(entry)}"
        )
    found = file_sha256(entry.path)
    if found != entry.sha256:
        size = entry.path.stat().st_size
        sizes = f"{size} bytes, {entry.size} expected" if size != entry.size else f"{size} bytes, as expected"
        raise ModelDigestError(
            f"{entry.path}: the {entry.source} model {entry.name!r} is damaged or was replaced: its SHA-256 is "
            f"{found}, {entry.registry} expects {entry.sha256} ({sizes}); {_remedy(entry)}",
            path=entry.path, expected=entry.sha256, found=found,
        )
    return str(entry.path)


# ------------------------------------------------------------------ what a file is, from its metadata
def _ranges(values) -> str:
    """[1000, 1001, …, 1009, 2500] -> '1000–1009, 2500'."""
    vals = sorted({int(v) for v in values})
    out, i = [], 0
    while i < len(vals):
        j = i
        while j + 1 < len(vals) and vals[j + 1] == vals[j] + 1:
            j += 1
        out.append(str(vals[i]) if i == j else f"{vals[i]}–{vals[j]}")
        i = j + 1
    return ", ".join(out)


def _sims(seeds, scenarios, frames, count=None) -> str:
    n = count if count else len(seeds) * max(len(scenarios), 1)
    what = f"seeds {_ranges(seeds)}" + (f" × {', '.join(scenarios)}" if scenarios else "")
    return f"{n} simulated drives ({what}" + (f"; {frames} sweeps each)" if frames else ")")


def trained_on(training_data) -> str:
    """One line on the weights' training, from the ``radar_odom.training_data`` record (its ``train`` part)."""
    td = _record(training_data)
    if isinstance(td, str):
        return td or "not recorded in the file"
    tr = td.get("train") or {}
    if not tr:
        return "not recorded in the file"
    parts = []
    if tr.get("sim_seeds"):
        sims = _sims(tr["sim_seeds"], tr.get("scenarios") or [], tr.get("frames"), len(tr.get("train_drives") or []))
        if tr.get("sensor"):
            sims += f", {tr['sensor']} radars"
        if tr.get("train_pairs"):
            sims += f", {tr['train_pairs']} pairs"
        parts.append(sims)
    if tr.get("data"):
        parts.append("recordings " + ", ".join(Path(p).name for p in tr["data"]))
    if tr.get("real"):
        parts.append("real pairs from " + ", ".join(Path(p).name for p in tr["real"]))
    if tr.get("val_seeds"):
        val = f"validation: seeds {_ranges(tr['val_seeds'])}"
        extra = [f"{tr['val_pairs']} pairs" if tr.get("val_pairs") else "",
                 f"{tr['val_sensor']} radar" if tr.get("val_sensor") else ""]
        parts.append(val + (f" ({', '.join(e for e in extra if e)})" if any(extra) else ""))
    if tr.get("objective") == "distil" or tr.get("distill_from"):
        w = tr.get("distill_pose_weight") or 0
        pose = f" + {w:g} × pose cross-entropy" if w else ""
        parts.append(f"distilled from {tr.get('distill_from')}'s mirror-averaged masks{pose}")
    elif tr.get("supervised_masks"):
        parts.append("supervised masks")
    elif tr.get("pose_loss"):
        parts.append("pose cross-entropy" if tr["pose_loss"] == "ce" else f"pose loss {tr['pose_loss']}")
    if tr.get("init_from"):
        parts.append(f"started from {Path(str(tr['init_from'])).name}")
    if tr.get("adapt"):
        parts.append("adapted (radar-odom adapt)" + (f" from {tr['adapt']['base']}" if tr["adapt"].get("base") else ""))
    if tr.get("steps"):
        parts.append(f"{tr['steps']} steps" + (f", best epoch {tr['best_epoch']}" if tr.get("best_epoch") else ""))
    return "; ".join(parts) if parts else "not recorded in the file"


def calibrated_on(training_data) -> str:
    """One line on the covariance's calibration, from the ``radar_odom.training_data`` record."""
    td = _record(training_data)
    c = td.get("calibration") if isinstance(td, dict) else None
    if not c:
        return "no calibration recorded in the file"
    drives = c.get("drives") or []
    n_sim = len([d for d in drives if not str(d).startswith("real:")])
    parts = [_sims(c.get("sim_seeds") or [], c.get("scenarios") or [], c.get("frames"), n_sim)
             if c.get("sim_seeds") else ""]
    if c.get("real"):
        held = f", its last {c['real_holdout']} sweeps held out" if c.get("real_holdout") else ""
        parts.append("real: " + ", ".join(Path(p).name for p in c["real"]) + held)
    line = " + ".join(p for p in parts if p) or "drives not recorded"
    facts = []
    if c.get("pairs"):
        facts.append(f"{c['pairs']} pairs")
    if isinstance(c.get("mean_d2"), (int, float)):
        facts.append(f"mean d² {c['mean_d2']:.2f}" + (f" (target {c['target']:g})" if c.get("target") else ""))
    if isinstance(c.get("beta_cov"), (int, float)):
        facts.append(f"β_cov {c['beta_cov']:.3f}")
    return line + (f"; {', '.join(facts)}" if facts else "")


def _record(training_data):
    if isinstance(training_data, dict):
        return training_data
    try:
        value = json.loads(training_data or "{}")
    except (TypeError, json.JSONDecodeError):
        return str(training_data)
    return value if isinstance(value, dict) else str(training_data)


def search_label(search: dict | None) -> str:
    """'fast (c4s3b2)' (coarse stage on 1/4-size images at every 3rd yaw, a band of ±2 yaws), 'decoupled',
    or 'exhaustive' (every yaw scored: no search record), as docs/latency.md writes them."""
    if not search:
        return "exhaustive"
    if search.get("kind") == "coarse_to_fine":
        return (f"fast (c{search.get('coarse_factor')}s{search.get('coarse_stride')}"
                f"b{search.get('band_half_width')})")
    return str(search.get("kind") or "unknown")


def read_metadata(path) -> dict[str, str]:
    """The file's ONNX metadata (``radar_odom.*`` keys), read by onnxruntime without optimising the graph."""
    import onnxruntime as ort

    from .errors import InvalidModelError

    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own classes for a file that is not ONNX
        raise InvalidModelError(f"{path}: onnxruntime cannot load it as an ONNX model ({exc})") from None
    return dict(sess.get_modelmeta().custom_metadata_map)


def describe(path) -> dict:
    """The registry fields of a radar-odom ONNX file: ``sha256``, ``size`` and what its metadata says (grid, form,
    search, training and calibration). A file that is not a radar-odom model raises `ModelMismatchError` /
    `InvalidModelError` (`radar_odom.model_file.ModelInfo.from_metadata`)."""
    from .model_file import ModelInfo

    path = Path(path)
    info = ModelInfo.from_metadata(read_metadata(path), str(path))
    p = info.profile
    if p.input_kind == "polar":
        grid = f"polar, {info.sweep_geometry['num_azimuths']} azimuths × {info.polar_input['num_bins']} bins"
    else:
        grid = f"{p.resolution_m:g} m × {p.width_px} px"
    form = info.form + (" (int8 masker)" if info.quantization else "")
    return {
        "sha256": file_sha256(path), "size": path.stat().st_size, "grid": grid, "form": form,
        "search": search_label(info.search), "trained_on": trained_on(info.training_data),
        "calibrated_on": calibrated_on(info.training_data),
    }


# ------------------------------------------------------------------ writing: the local registry, the shipped refresh
def write_registry(folder, entries: dict[str, dict]) -> Path:
    """Write ``folder/registry.json`` from plain entries (name -> the JSON object), whole (a temporary file
    renamed over it), names sorted."""
    reg = registry_path(folder)
    reg.parent.mkdir(parents=True, exist_ok=True)
    text = json.dumps({"format": FORMAT, "models": {k: entries[k] for k in sorted(entries)}},
                      indent=2, ensure_ascii=False) + "\n"
    tmp = reg.with_name(f".{reg.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, reg)
    return reg


def add_local(name: str, file, force: bool = False) -> Entry:
    """Copy ``file`` (a radar-odom ONNX model) into `local_dir` as ``NAME.onnx`` and record it, with its digest,
    in the local registry; returns its entry. Refuses a name that is not one, a shipped model's name, a local
    name already taken (unless ``force``), and a file that is not a radar-odom model."""
    import shutil

    from .errors import ConfigError

    if not valid_name(name):
        raise ConfigError(f"{name!r} is not a model name: letters, digits, '.', '_' and '-', not starting with '.'")
    src = Path(file)
    if not src.is_file():
        raise ModelNotFoundError(f"{src}: no such model file")
    shipped = read_registry(SHIPPED_DIR, "shipped") or {}
    if name in shipped:
        raise ConfigError(f"{name!r} is a shipped model's name; give your model another name")
    folder = local_dir()
    local = read_registry(folder, "local") or {}
    if name in local and not force:
        raise ConfigError(f"a local model {name!r} is already registered ({local[name].path}); "
                          "add --force to replace it, or choose another name")
    facts = describe(src)  # refuses a file that is not a radar-odom model, before anything is written
    folder.mkdir(parents=True, exist_ok=True)
    dest = folder / f"{name}.onnx"
    tmp = folder / f".{name}.onnx.{os.getpid()}.tmp"
    shutil.copyfile(src, tmp)
    if file_sha256(tmp) != facts["sha256"]:
        tmp.unlink()
        raise ModelDigestError(f"{src}: the file changed while it was copied; add it again", path=src)
    os.replace(tmp, dest)
    entries = {k: e.to_json() for k, e in local.items()}
    entries[name] = {"file": dest.name, **facts, "scorecard": None}
    write_registry(folder, entries)
    return read_registry(folder, "local")[name]


def remove_local(name: str) -> Path:
    """Remove the local model ``name`` (its entry and its file); returns the file's path."""
    from .errors import ConfigError

    folder = local_dir()
    local = read_registry(folder, "local") or {}
    if name not in local:
        names = ", ".join(sorted(local)) or "none"
        raise ConfigError(f"no local model {name!r} in {registry_path(folder)} (local models: {names})")
    entry = local.pop(name)
    write_registry(folder, {k: e.to_json() for k, e in local.items()})
    entry.path.unlink(missing_ok=True)
    return entry.path


def refresh_shipped(folder=None) -> dict[str, dict]:
    """Rewrite the shipped registry's measured fields from the files in ``folder`` (default `SHIPPED_DIR`):
    one entry per ``*.onnx``, its ``scorecard`` quote kept (null for a new file). Returns the entries written."""
    folder = Path(folder) if folder else SHIPPED_DIR
    old = read_registry(folder, "shipped") or {}
    entries = {}
    for path in sorted(folder.glob("*.onnx")):
        entries[path.stem] = {"file": path.name, **describe(path),
                              "scorecard": old[path.stem].scorecard if path.stem in old else None}
    write_registry(folder, entries)
    return entries


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m radar_odom.model_registry", description=refresh_shipped.__doc__)
    parser.add_argument("--refresh", action="store_true", help="rewrite radar_odom/models/registry.json")
    args = parser.parse_args(argv)
    if not args.refresh:
        parser.print_help()
        return 2
    for name, e in refresh_shipped().items():
        print(f"{name}: {e['sha256']} {e['size']} bytes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
