"""Which models to profile: given names or paths, shipped ones, or untrained exports."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from ..errors import EXPORT_INSTALL_HINT, RadarOdomError


def untrained_model(profile_name: str, out_dir, search: str = "fast") -> Path:
    """Export (once; cached in ``out_dir``) an untrained learned-mask model of ``profile_name``.

    Runs in a child interpreter: this needs torch (the radar-odom-export distribution, `EXPORT_INSTALL_HINT`), and
    keeping it out of this process keeps the memory figures honest.
    """
    path = Path(out_dir) / f"untrained-{profile_name}-{search}.onnx"
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run([sys.executable, "-m", "radar_odom_export.untrained", profile_name, str(path), search],
                          capture_output=True, text=True, check=False)
    if proc.returncode:
        if "No module named 'torch'" in proc.stderr or "No module named 'radar_odom_export'" in proc.stderr:
            raise RadarOdomError(
                f"no model given for {profile_name} and torch is not installed to export an untrained "
                f"one: leave it out (--profiles with the others, e.g. --profiles cart-0.8 cart-0.4), pass "
                f"--models PATH.onnx, or install the torch side, radar-odom-export ({EXPORT_INSTALL_HINT})")
        raise RadarOdomError(f"exporting an untrained {profile_name} model failed:\n{proc.stderr[-2000:]}")
    return path


def resolve_models(models, profiles, out_dir, search: str = "fast", echo=print) -> list[tuple[str, Path, bool]]:
    """(label, path, untrained) per model: the given ones (names or paths), then for each of
    ``profiles`` not covered by them (same resolution and width) the shipped model of that name,
    or failing that an untrained export."""
    from ..model_zoo import pretrained, pretrained_names, resolve_model
    from ..onnx_model import ModelInfo
    from ..profiles import get_profile

    chosen, covered = [], set()

    def add(label, path, untrained):
        prof = _read_profile(path, ModelInfo)
        chosen.append((label, Path(path), untrained))
        covered.add((prof.resolution_m, prof.width_px))

    for spec in models or ():
        add(Path(spec).stem if spec.endswith(".onnx") else spec, resolve_model(spec), False)
    shipped = set(pretrained_names())
    for name in profiles or ():
        p = get_profile(name)
        if (p.resolution_m, p.width_px) in covered:
            continue
        if name in shipped:
            add(name, pretrained(name), False)
            continue
        cached = Path(out_dir) / "models" / f"untrained-{name}-{search}.onnx"
        echo(f"{name}: no model given or shipped; " + ("using the untrained export in " + str(cached)
             if cached.is_file() else f"exporting an untrained one ({search} search; needs torch) ..."))
        add(f"{name} (untrained)", untrained_model(name, Path(out_dir) / "models", search), True)
    return chosen


def _read_profile(path, model_info_cls):
    """The `GridProfile` in a model's metadata (a session without graph optimisation: cheap)."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])
    return model_info_cls.from_metadata(dict(sess.get_modelmeta().custom_metadata_map), str(path)).profile

