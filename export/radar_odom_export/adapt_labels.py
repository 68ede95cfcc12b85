"""Pseudo-labels of many recordings in parallel on Ray workers, for `radar-odom adapt --ray / --address`.

The labels are the base model's own runtime chains (`adapt.run_runtime` over `adapt.read_recording`), one
recording per task: embarrassingly parallel, and torch-free (a task imports no torch; training stays on
the driver, or under torchrun, as `train` does). Only paths go out and two small arrays per recording
come back; each worker reads its recording from a file system every node sees.
"""
from __future__ import annotations

from pathlib import Path


def label_recording(model_path, source, topic, sweeps: slice, threads: int | None):
    """(absolute poses float64[N, 3, 3], relative poses float64[N − 1, 3]) of ``model_path`` over the sweeps
    ``adapt`` reads from ``source``: what `adapt.adapt` computes for it on the driver."""
    from .adapt import read_recording, run_runtime

    rec = read_recording(source, topic, sweeps)
    return run_runtime(model_path, rec.scans, threads, desc=f"pseudo-labels {rec.name}")


def ray_labeller(address: str | None = None, threads: int | None = None):
    """A ``labeller`` for `adapt.adapt`: ``(model_path, sources, topic, sweeps) -> [(poses, rel), …]`` in the
    order of ``sources``, each a Ray task (``threads`` onnxruntime threads each; default: the cluster's CPUs
    shared among the recordings, `radar_odom.fleet.scheduler.default_threads`). ``address`` as for
    `radar-odom fleet`: None starts a local Ray for the call. An address that cannot be one is a `ConfigError`
    now, and one where nothing listens a `ClusterError` (`radar_odom.fleet.scheduler.check_ray_address`,
    `probe_ray_address`): not after the recordings are read; joining the cluster is given
    `RAY_CONNECT_TIMEOUT_S` when the labels are asked for."""
    from radar_odom.fleet.scheduler import check_ray_address, probe_ray_address

    address = check_ray_address(address)
    if address not in (None, "auto"):
        probe_ray_address(address)

    def label(model_path, sources, topic, sweeps):
        from radar_odom.fleet.scheduler import default_threads, node_cpus, ray_connection

        with ray_connection(address) as ray:
            n = threads or default_threads(node_cpus(ray), len(sources))
            task = ray.remote(num_cpus=n, max_retries=1)(label_recording)  # a worker lost: tried once more
            refs = [task.remote(str(Path(model_path).resolve()), str(Path(s).resolve()), topic, sweeps, n)
                    for s in sources]
            return ray.get(refs)

    return label
