"""A radar-odom model file on another runtime than onnxruntime's CPU provider: OpenVINO's own, or onnxruntime's
OpenVINO execution provider.

    from radar_odom.runtimes import OpenVinoModel, load_model
    odo = RadarOdometer(OpenVinoModel(radar_odom.pretrained("cart-0.4")))
    odo = RadarOdometer(load_model(radar_odom.pretrained("cart-0.4"), "onnxruntime-openvino"))

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

``"onnxruntime-openvino"`` (`openvino_ep_session`) is an `OnnxModel` whose whole graph runs on onnxruntime's
``OpenVINOExecutionProvider`` (CPU, f32): a node the provider refuses is an error, not a silent fallback to
onnxruntime's CPU provider (the graph is changed instead: docs/latency.md). Either package brings the provider:

* the ``onnxruntime-openvino`` wheel, an onnxruntime built with that provider; it *replaces* the
  ``onnxruntime`` package (both install the ``onnxruntime`` module), so give it an environment of its own;
* the ``onnxruntime-ep-openvino`` plugin library, registered into the stock onnxruntime (≥ 1.23). Its
  1.8.1 offers only Intel hardware (it skips every device whose vendor id is not 0x8086), so on an AMD CPU
  it offers no device and the runtime says so.
"""
from __future__ import annotations

import importlib

import numpy as np

from .errors import ConfigError, InvalidModelError, MissingExtraError
from .onnx_model import OnnxModel, check_threads
from .sweep_arrays import check_sweep_feeds

# f32 arithmetic throughout and no Snippets fusion: the poses of onnxruntime (module docstring)
OPENVINO_CPU_CONFIG = {"INFERENCE_PRECISION_HINT": "f32", "SNIPPETS_MODE": "DISABLE"}
RUNTIMES = ("onnxruntime", "openvino", "onnxruntime-openvino")
OPENVINO_EP = "OpenVINOExecutionProvider"
# the provider's CPU device computing in f32, as OpenVINO's own runtime is asked to (the DFT matmuls need f32)
OPENVINO_EP_OPTIONS = {"device_type": "CPU", "precision": "FP32"}
OPENVINO_EP_PLUGIN = "onnxruntime_ep_openvino"  # the plugin package's module
INTEL_VENDOR_ID = 0x8086
# every node on the OpenVINO provider, or no session: a graph split with onnxruntime's CPU provider does not
# "run on OpenVINO"
WHOLE_GRAPH = {"session.disable_cpu_ep_fallback": "1"}


class OpenVinoModel:
    """A radar-odom ONNX file compiled by OpenVINO (``pip install openvino``; in the ``dev`` extra).

    Args:
        path: the ``.onnx`` file. threads: CPU inference threads (default: OpenVINO's choice).
        device: OpenVINO device name (default ``"CPU"``). config: compile properties (default
            `OPENVINO_CPU_CONFIG` on the CPU, none elsewhere); replaces the default, not merged.
    """

    def __init__(self, path, threads: int | None = None, device: str = "CPU", config: dict | None = None):
        from collections.abc import Mapping

        if not isinstance(device, str) or not device.strip():
            raise ConfigError(f"device must be an OpenVINO device name such as 'CPU', got {device!r}")
        if config is not None and not (isinstance(config, Mapping) and all(isinstance(k, str) for k in config)):
            raise ConfigError(f"config must be a dict of OpenVINO compile properties (e.g. {OPENVINO_CPU_CONFIG}), "
                              f"got {config!r}")
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
        """Outputs by name for float32 ``feeds`` by input name (`OnnxModel.run`'s contract: a sweep-form model's
        sweep arrays checked as the SDK checks a sweep, a feed that does not fit the graph an `InvalidModelError`,
        as there); arrays are copies."""
        names = list(feeds) if isinstance(feeds, dict) else None
        if names is None or sorted(names) != sorted(self.info.inputs):
            given = "not a dict" if names is None else f"given {names}"
            raise InvalidModelError(f"{self.path}: OpenVINO cannot run the model on this feed (the graph's inputs "
                                    f"are {list(self.info.inputs)}, {given})")
        if self.info.form == "sweep":  # the sweep's arrays, checked as OnnxModel.run checks them
            check_sweep_feeds(feeds, self.info, self.path.name)
        try:
            result = self._request.infer(feeds)
        except Exception as exc:  # noqa: BLE001 - OpenVINO's RuntimeError: where it checked, then what failed
            lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
            detail = (lines[-1] if lines else type(exc).__name__)[:200]
            raise InvalidModelError(f"{self.path}: OpenVINO failed running the model ({detail})") from None
        return {name: np.array(result[port]) for name, port in self._outputs.items()}


def openvino_ep_session(threads: int | None = None) -> dict:
    """`OnnxModel`'s keyword arguments that put a graph on onnxruntime's OpenVINO execution provider (CPU, f32,
    ``threads`` inference threads): ``providers`` where this onnxruntime has the provider built in (the
    ``onnxruntime-openvino`` wheel), else ``ep_devices``/``ep_options`` from the ``onnxruntime-ep-openvino`` plugin.

    Raises `MissingExtraError` where neither package is installed, `ConfigError` where the plugin offers no CPU
    device here (its 1.8.1 offers only Intel hardware)."""
    import onnxruntime as ort

    options = dict(OPENVINO_EP_OPTIONS)
    if check_threads(threads):
        options["num_of_threads"] = str(threads)
    if OPENVINO_EP in ort.get_available_providers():
        return {"providers": [(OPENVINO_EP, options)], "session_config": WHOLE_GRAPH}
    try:
        plugin = importlib.import_module(OPENVINO_EP_PLUGIN)
    except ImportError:
        raise MissingExtraError(
            "onnxruntime-openvino", None,
            how="pip install onnxruntime-openvino, in an environment of its own (it replaces the onnxruntime "
                f"package; onnxruntime {ort.__version__} here has no {OPENVINO_EP}), or on an Intel CPU pip install "
                "onnxruntime-ep-openvino (a plugin for the stock onnxruntime)") from None
    devices = _plugin_cpu_devices(ort, plugin)
    if not devices:
        vendors = ", ".join(sorted({f"{d.device.vendor} {d.device.vendor_id:#06x}" for d in ort.get_ep_devices()
                                    if d.device.type == ort.OrtHardwareDeviceType.CPU}))
        raise ConfigError(f"{OPENVINO_EP_PLUGIN} offers no CPU device here (this CPU: {vendors or 'unknown'}; the "
                          f"plugin offers only Intel ones, vendor id {INTEL_VENDOR_ID:#06x}): use the "
                          "onnxruntime-openvino wheel in an environment of its own, or runtime 'openvino'")
    options.pop("device_type")  # the device is chosen: the plugin's CPU device
    return {"ep_devices": devices[:1], "ep_options": options, "session_config": WHOLE_GRAPH}


_registered_plugins: set = set()


def _plugin_cpu_devices(ort, plugin) -> list:
    """The plugin's OpenVINO CPU devices, the library registered with onnxruntime once per process."""
    if OPENVINO_EP_PLUGIN not in _registered_plugins:
        ort.register_execution_provider_library(OPENVINO_EP_PLUGIN, plugin.get_library_path())
        _registered_plugins.add(OPENVINO_EP_PLUGIN)
    return [d for d in ort.get_ep_devices()
            if d.ep_name == plugin.get_ep_name() and d.ep_metadata.get("ov_device") == "CPU"]


def load_model(path, runtime: str = "onnxruntime", threads: int | None = None):
    """An `OnnxModel` (``runtime="onnxruntime"``: its CPU provider; ``"onnxruntime-openvino"``: its OpenVINO
    provider, `openvino_ep_session`) or `OpenVinoModel` (``"openvino"``) of ``path``."""
    if runtime == "onnxruntime":
        return OnnxModel(path, threads=threads)
    if runtime == "openvino":
        return OpenVinoModel(path, threads=threads)
    if runtime == "onnxruntime-openvino":
        try:
            return OnnxModel(path, threads=threads, **openvino_ep_session(threads))
        except InvalidModelError as exc:
            if "fallback to CPU EP" not in str(exc):
                raise
            raise InvalidModelError(f"{path}: onnxruntime's OpenVINO provider cannot run every node of this graph "
                                    "(it would leave some to onnxruntime's CPU provider)") from None
    raise ConfigError(f"runtime must be one of {', '.join(RUNTIMES)}, got {runtime!r}")
