"""A radar-odom model file on another runtime than onnxruntime: OpenVINO's own.

    from radar_odom.runtimes import OpenVinoModel
    odo = RadarOdometer(OpenVinoModel(radar_odom.pretrained("cart-0.4")))

`OpenVinoModel` has `OnnxModel`'s interface (``info``, ``path``, ``run(feeds)``), so `RadarOdometer`
and the tooling take it in its place. The file is read and checked as the runtime always reads it
(`OnnxModel`: metadata and signature), then compiled by OpenVINO with `OPENVINO_CPU_CONFIG`.

Why that configuration (docs/latency.md, "Runtimes and the sweep form"): OpenVINO's CPU plugin
computes in bf16 where the CPU has it unless asked for f32 (the DFT matmuls need f32), and its
*Snippets* (elementwise subgraphs fused into JIT kernels) compute the shipped graphs' polar rotation
differently from the graph as written: with them (f32), poses were up to 2.1 cm / 0.0041 rad (cart-0.4) and
3.8 cm / 0.0042 rad (cart-0.8) from onnxruntime's over 5 simulated pairs, on its own state chain or fed
onnxruntime's states alike (so not the chain; ``EXECUTION_MODE_HINT: ACCURACY`` does not help). Exposing the
Mul outputs of the rotation's radial interpolation (``Clip → Floor → Sub`` feeding the taps) as graph outputs,
which splits the fused kernels there, removes the difference, as ``SNIPPETS_MODE: DISABLE`` does (2e-6 m, 1e-7 rad).
"""
from __future__ import annotations

import numpy as np

from .errors import InvalidModelError, MissingExtraError
from .onnx_model import OnnxModel, check_threads

# f32 arithmetic throughout and no Snippets fusion: the poses of onnxruntime (module docstring)
OPENVINO_CPU_CONFIG = {"INFERENCE_PRECISION_HINT": "f32", "SNIPPETS_MODE": "DISABLE"}
RUNTIMES = ("onnxruntime", "openvino")


class OpenVinoModel:
    """A radar-odom ONNX file compiled by OpenVINO (``pip install openvino``; in the ``dev`` extra).

    Args:
        path: the ``.onnx`` file. threads: CPU inference threads (default: OpenVINO's choice).
        device: OpenVINO device name (default ``"CPU"``). config: compile properties (default
            `OPENVINO_CPU_CONFIG` on the CPU, none elsewhere); replaces the default, not merged.
    """

    def __init__(self, path, threads: int | None = None, device: str = "CPU", config: dict | None = None):
        try:
            import openvino as ov
        except ImportError as exc:
            raise MissingExtraError("openvino", "dev") from exc
        threads = check_threads(threads)
        checked = OnnxModel(path, threads=1)  # the file's metadata and graph, held as onnxruntime loads it
        self.path, self.info, self.output_names = checked.path, checked.info, checked.output_names
        del checked
        props = dict(OPENVINO_CPU_CONFIG if config is None and device == "CPU" else (config or {}))
        if threads:
            props["INFERENCE_NUM_THREADS"] = threads
        try:
            self._compiled = ov.Core().compile_model(str(self.path), device, props)
        except Exception as exc:  # noqa: BLE001 - OpenVINO raises its own RuntimeError subclasses
            detail = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
            raise InvalidModelError(f"{self.path}: OpenVINO cannot compile this model ({detail})") from None
        self._request = self._compiled.create_infer_request()
        self._outputs = {name: self._compiled.output(name) for name in self.output_names}

    def run(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Outputs by name for float32 ``feeds`` by input name (`OnnxModel.run`'s contract); arrays are copies."""
        result = self._request.infer(feeds)
        return {name: np.array(result[port]) for name, port in self._outputs.items()}


def load_model(path, runtime: str = "onnxruntime", threads: int | None = None):
    """An `OnnxModel` (``runtime="onnxruntime"``) or `OpenVinoModel` (``"openvino"``) of ``path``."""
    if runtime == "onnxruntime":
        return OnnxModel(path, threads=threads)
    if runtime == "openvino":
        return OpenVinoModel(path, threads=threads)
    from .errors import ConfigError

    raise ConfigError(f"runtime must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
