"""Recordings as Ray tasks on a pool of actors, one onnxruntime session each, reused across recordings.

Each actor (`FleetWorker`) asks Ray for ``threads`` CPUs and loads the model once; the driver hands a
recording to whichever actor is free (`ray.wait`), so a node runs as many recordings at once as it has
slots (its CPUs // threads). A recording that fails (an error in it, or its worker killed: the actor is
then replaced) is queued once more at the end, then reported with its one-line reason; the others go on.
Only paths and small dicts cross the object store: every node reads its recordings from, and writes its
outputs to, a file system they all see (the same paths on every node).
"""
from __future__ import annotations

import re
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from .job import one_line, process_recording
from .manifest import check_fleet_outputs, done_row, file_sha256, job_key, recording_names
from .report import FAILED, KEPT, failed_row

RETRIES = 1  # a failing recording is tried once more, then reported
RAY_CONNECT_TIMEOUT_S = 30.0  # to join a running cluster; ray.init alone retries for minutes or for ever
# HOST:PORT: a host name or IPv4 address, or an [IPv6] one, and a port number
_HOST_PORT = re.compile(r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?):(?P<port>[0-9]{1,5})")


def import_ray():
    """``ray``, or `MissingExtraError` with the pip line (Ray is the optional ``fleet`` extra)."""
    try:
        import ray
    except ImportError:
        from ..errors import MissingExtraError

        raise MissingExtraError("ray", "fleet") from None
    return ray


def check_ray_address(address, flag: str = "--address") -> str | None:
    """``address`` as given (None: a local Ray; ``"auto"``; ``HOST:PORT``, port 1-65535), or `ConfigError` in
    one line, at once: nothing is asked of Ray for an address that cannot be one (``garbage``, ``host:text``)."""
    from ..errors import ConfigError

    if address is None:
        return None
    text = address.strip() if isinstance(address, str) else ""
    match = _HOST_PORT.fullmatch(text)
    if text != "auto" and not (match and 1 <= int(match["port"]) <= 65535):
        raise ConfigError(f"{flag} {address!r}: give 'auto' (the Ray cluster this machine belongs to) or HOST:PORT "
                          "of a running cluster's head (e.g. 10.0.0.5:6379; `ray status` on the head prints it)")
    return text


def probe_ray_address(address: str, timeout_s: float = RAY_CONNECT_TIMEOUT_S) -> None:
    """`ClusterError` where nothing accepts a connection at ``address`` (HOST:PORT) within ``timeout_s``: the
    port refused, the host unknown or unreachable. Cheap (one TCP connection): done before anything else."""
    import socket

    from ..errors import ClusterError

    host, port = address.rsplit(":", 1)
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        reason = f"no answer within {timeout_s:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise ClusterError(f"--address {address}: no Ray cluster there ({reason}); start one (ray start --head) or "
                           "give the address its head prints") from None


def connect_ray(ray, address: str | None, timeout_s: float = RAY_CONNECT_TIMEOUT_S, **init_kwargs) -> None:
    """``ray.init`` for ``address`` (`check_ray_address`; None starts a local Ray), or `ClusterError` naming the
    address and the reason: nothing listening there (`probe_ray_address`), no cluster for ``auto``, or no Ray
    answering within ``timeout_s`` (``ray.init`` runs on a thread it is given that long: on its own it retries
    for minutes against a port that accepts connections but is no Ray head)."""
    import logging
    import threading

    from ..errors import ClusterError

    address = check_ray_address(address)
    if address is None:  # "local": a new Ray even where a cluster runs on this machine (None would join that one)
        with _sigterm_kept():
            try:
                ray.init(address="local", **init_kwargs)
            except Exception as exc:  # noqa: BLE001 - Ray's own errors, one line each
                raise ClusterError(f"cannot start a local Ray on this machine ({one_line(exc)})") from None
        return
    deadline = time.monotonic() + timeout_s  # the probe and the join share the one timeout
    if address != "auto":
        probe_ray_address(address, timeout_s)
    outcome: dict = {}

    def connect():
        try:
            ray.init(address=address, **init_kwargs)
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            outcome["error"] = exc

    quiet = _DropSigtermNotice()
    worker_log = logging.getLogger("ray._private.worker")
    worker_log.addFilter(quiet)
    try:
        thread = threading.Thread(target=connect, name="ray-connect", daemon=True)
        thread.start()
        thread.join(max(deadline - time.monotonic(), 0.1))
    finally:
        worker_log.removeFilter(quiet)
    if thread.is_alive():
        raise ClusterError(f"--address {address}: no Ray cluster answered within {timeout_s:g} s (is that port a Ray "
                           "head's? `ray status` on the head prints its address)")
    if "error" in outcome:
        raise ClusterError(f"--address {address}: cannot join the Ray cluster ({one_line(outcome['error'])})")
    _exit_on_sigterm()


class _DropSigtermNotice:
    """A logging filter: Ray's warning that a ``ray.init`` off the main thread sets no SIGTERM handler
    (`_exit_on_sigterm` sets the one it would have)."""

    @staticmethod
    def filter(record) -> bool:
        return "SIGTERM handler is not set" not in record.getMessage()


@contextmanager
def _sigterm_kept():
    """``ray.init`` on the main thread sets SIGTERM to ``sys.exit(15)``: a handler the caller had set before (the
    command line's, which unwinds as Ctrl-C does and says so in one line: commands/interrupts.py) is put back after.
    Where none was set (the default), Ray's stays, as before."""
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    before = signal.getsignal(signal.SIGTERM) if main else None
    try:
        yield
    finally:
        if callable(before) and signal.getsignal(signal.SIGTERM) is not before:
            signal.signal(signal.SIGTERM, before)


def _exit_on_sigterm() -> None:
    """What ``ray.init`` does on the main thread: SIGTERM exits through ``sys.exit`` (the ``finally`` blocks run:
    the workers are let go); only where nothing else handles SIGTERM yet."""
    import signal
    import sys
    import threading

    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL:
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))


@contextmanager
def ray_connection(address: str | None = None, timeout_s: float = RAY_CONNECT_TIMEOUT_S):
    """Yields ``ray``, connected: to the cluster at ``address`` ("auto", "HOST:PORT"; `connect_ray`: a
    `ClusterError` in one line where it cannot be joined within ``timeout_s``), or a local Ray started for this
    block when None; a process already connected keeps its connection (and it stays open after). Workers'
    output stays in Ray's logs (``log_to_driver=False``): the command line prints its own lines."""
    import logging

    ray = import_ray()
    started = not ray.is_initialized()
    if started:
        connect_ray(ray, address, timeout_s, include_dashboard=False, log_to_driver=False,
                    logging_level=logging.WARNING, configure_logging=True)
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def node_cpus(ray) -> list[float]:
    """CPUs of each live node of the connected cluster that has any; `ConfigError` when none has."""
    from ..errors import ConfigError

    cpus = [n["Resources"].get("CPU", 0.0) for n in ray.nodes() if n["Alive"] and n["Resources"].get("CPU")]
    if not cpus:
        raise ConfigError("the Ray cluster has no node with CPUs to run on")
    return cpus


class FleetWorker:
    """A Ray actor's state: the model's onnxruntime session, loaded once, run over recording after recording."""

    def __init__(self, model_path: str, threads: int):
        from ..onnx_model import OnnxModel

        self.model = OnnxModel(model_path, threads)
        self.threads = threads

    def process(self, recording: str, out_root: str, name: str, options: dict, key: str) -> dict:
        """{"ok": True, "row": …} or {"ok": False, "reason": one line}; the row names the node it ran on."""
        import ray

        node = ray.get_runtime_context().get_node_id()[:8]
        try:
            row = process_recording(self.model, recording, out_root, name, options, key)
        except Exception as exc:  # any failure is this recording's: reported, the worker stays
            return {"ok": False, "reason": one_line(exc), "node": node}
        row["node"] = node
        return {"ok": True, "row": row}


def default_threads(node_cpus: list[float], recordings: int) -> int:
    """onnxruntime threads per recording: one per CPU when there are at least as many recordings as CPUs
    (recordings in parallel scale better than threads inside one), else the CPUs shared among them, at
    most one node's worth."""
    total = sum(node_cpus)
    return max(1, min(int(min(node_cpus)), int(total // max(recordings, 1))))


@dataclass
class FleetRun:
    """What `run_fleet` did: the rows in the order of the recordings, and the pace of this run."""

    rows: list
    wall_s: float = 0.0
    threads: int = 0
    workers: int = 0
    nodes: int = 0

    @property
    def failed(self) -> list:
        return [r for r in self.rows if r["status"] == FAILED]


def run_fleet(recordings, out_dir, model_path, options: dict, *, address: str | None = None,
              threads: int | None = None, show_progress: bool = True, retries: int = RETRIES) -> FleetRun:
    """Process ``recordings`` (paths) with `radar-odom run`'s ``options`` (`commands.run.sequence_options`),
    each into ``out_dir/<name>``; skip those whose outputs are complete and valid for their inputs, the
    model and the options (`manifest.done_row`). ``address``: None starts a local Ray (unless this process
    is connected already), else ``"auto"`` or ``HOST:PORT`` of a running cluster."""
    from ..onnx_model import OnnxModel

    t0 = time.perf_counter()
    address = check_ray_address(address)
    recordings = [str(r) for r in recordings]
    names = recording_names(recordings)
    out_dir = Path(out_dir)
    # before any work: OUT apart from every recording, and each OUT/<name> new or fleet's own of that recording
    check_fleet_outputs(recordings, names, out_dir)
    OnnxModel(model_path, 1)  # a model no worker could load: its one-line error first, not one per recording
    model_sha = file_sha256(model_path)
    keys = [job_key(r, model_sha, options) for r in recordings]
    rows: list = [None] * len(recordings)
    for i, name in enumerate(names):
        row = done_row(out_dir / name, keys[i])
        if row is not None:
            row["status"] = KEPT
            rows[i] = row
    pending = [i for i, row in enumerate(rows) if row is None]
    run = FleetRun(rows)
    if pending:
        _run_on_ray(run, pending, recordings, names, keys, out_dir, model_path, options, address, threads,
                    show_progress, retries)
    run.wall_s = time.perf_counter() - t0
    return run


def _run_on_ray(run: FleetRun, pending, recordings, names, keys, out_dir, model_path, options, address, threads,
                show_progress, retries) -> None:
    from .._progress import progress
    from ..errors import ConfigError
    with ray_connection(address) as ray:
        out_dir.mkdir(parents=True, exist_ok=True)  # once a cluster is there to fill it
        cpus = node_cpus(ray)
        run.nodes = len(cpus)
        run.threads = threads or default_threads(cpus, len(pending))
        slots = sum(int(c // run.threads) for c in cpus)
        if slots == 0:
            raise ConfigError(f"--threads {run.threads}: no node of this cluster has that many CPUs "
                              f"(largest: {max(cpus):g})")
        actor_class = ray.remote(num_cpus=run.threads, max_restarts=0)(FleetWorker)
        model_path = str(Path(model_path).resolve())
        out_root = str(out_dir.resolve())
        recordings = [str(Path(r).resolve()) for r in recordings]
        free = [actor_class.remote(model_path, run.threads) for _ in range(min(slots, len(pending)))]
        run.workers = len(free)
        queue, attempts, in_flight = deque(pending), dict.fromkeys(pending, 0), {}
        sweeps, t0 = 0, time.perf_counter()
        bar = progress(total=len(recordings), desc="fleet", unit="rec", disable=not show_progress)
        bar.update(len(recordings) - len(pending))
        try:
            while queue or in_flight:
                while queue and free:
                    i, actor = queue.popleft(), free.pop()
                    ref = actor.process.remote(recordings[i], out_root, names[i], options, keys[i])
                    in_flight[ref] = (actor, i)
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in ready:
                    actor, i = in_flight.pop(ref)
                    attempts[i] += 1
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayError as exc:  # the worker died (killed, out of memory, node lost)
                        result = {"ok": False, "reason": f"worker lost: {one_line(exc)}"}
                        ray.kill(actor)
                        actor = actor_class.remote(model_path, run.threads)
                    free.append(actor)
                    if result["ok"]:
                        row = result["row"]
                        row["attempts"] = attempts[i]
                        run.rows[i] = row
                        sweeps += int(row["sweeps"])
                        bar.update(1)
                    elif attempts[i] <= retries:
                        queue.append(i)
                    else:
                        run.rows[i] = failed_row(names[i], recordings[i], result["reason"], attempts[i])
                        bar.update(1)
                done = sum(r is not None and r["status"] != FAILED for r in run.rows)
                bad = sum(r is not None and r["status"] == FAILED for r in run.rows)
                bar.set_postfix({"done": done, "failed": bad, "running": len(in_flight),
                                 "sweeps/s": f"{sweeps / max(time.perf_counter() - t0, 1e-9):.1f}"}, refresh=False)
        finally:
            bar.close()
            # interrupted or done: the workers go (nothing is published half-way: each job renames when done)
            for actor in free + [a for a, _ in in_flight.values()]:
                ray.kill(actor)
