"""What makes a fleet recording's outputs "done": a key over its inputs, the model and the options, and a
manifest beside the outputs that lists every file with its digest.

A recording is skipped on a re-run only when ``OUT/<name>/fleet-done.json`` exists, was written for the same
key, and every output it lists is there with the size and SHA-256 it recorded: a folder from an interrupted
run, an edited output or a changed input (a new sweep, another model, another option) is done again.

Inputs are keyed by each file's relative path, size and modification time (as make and rsync do), not by
its content: reading every sweep of a 30-minute drive to decide whether to skip it would cost as much as
a good part of running it. The model file is keyed by its content (a few MB).
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

MANIFEST = "fleet-done.json"
MANIFEST_VERSION = 1
# OUT itself: the report files, claimed by a manifest of their own before they are written (report.claim_reports)
REPORT_FILES = ("fleet.csv", "fleet.md", "fleet-error.png")
REPORTS_MANIFEST = ".radar-odom-fleet.json"
# names a recording's folder cannot take: the reports, their manifest, the report's temporary file
RESERVED_NAMES = (*REPORT_FILES, REPORTS_MANIFEST, ".fleet.csv.tmp")


def file_sha256(path) -> str:
    """SHA-256 hex of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def inputs_digest(recording) -> str:
    """SHA-256 hex over (relative path, size, mtime ns) of every file of ``recording`` (a folder, walked in
    sorted order, or one file such as a bag); a missing path digests as such (it then fails to run)."""
    root = Path(recording)
    h = hashlib.sha256()
    files = sorted(p for p in root.rglob("*") if p.is_file()) if root.is_dir() else [root] if root.exists() else []
    for p in files:
        st = p.stat()
        rel = p.name if p == root else p.relative_to(root).as_posix()
        h.update(f"{rel}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def job_key(recording, model_sha256: str, options: dict) -> str:
    """The key a recording's outputs are valid for: its inputs, the model's content and the run options
    (JSON, sorted keys; only those that change the outputs: not threads)."""
    text = json.dumps({"inputs": inputs_digest(recording), "model": model_sha256, "options": options},
                      sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def write_manifest(folder, key: str, row: dict) -> Path:
    """``folder/fleet-done.json``: the key, the report row, and every other file in ``folder`` with its size
    and SHA-256. Written last, inside the folder before it is renamed into place."""
    folder = Path(folder)
    files = {p.name: {"bytes": p.stat().st_size, "sha256": file_sha256(p)}
             for p in sorted(folder.iterdir()) if p.is_file() and p.name != MANIFEST}
    path = folder / MANIFEST
    path.write_text(json.dumps({"version": MANIFEST_VERSION, "key": key, "row": row, "files": files}, indent=1))
    return path


def done_row(folder, key: str) -> dict | None:
    """The report row stored in ``folder``'s manifest when its outputs are complete and valid for ``key``
    (every listed file present with its size and digest), else None (not done: process it again)."""
    folder = Path(folder)
    try:
        manifest = json.loads((folder / MANIFEST).read_text())
        if manifest.get("version") != MANIFEST_VERSION or manifest.get("key") != key:
            return None
        for name, want in manifest["files"].items():
            path = folder / name
            if not path.is_file() or path.stat().st_size != want["bytes"] or file_sha256(path) != want["sha256"]:
                return None
        return dict(manifest["row"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):  # missing, half-written or edited: not done
        return None


def recording_names(recordings) -> list[str]:
    """One output folder name per recording: its own name, or ``<parent>-<name>`` where two recordings of the
    command share a name (two vehicles' ``2019-01-10``); `ConfigError` where even those collide (the same path
    twice) or where a name is one of the report's (`RESERVED_NAMES`: a recording folder named ``fleet.csv``)."""
    from ..errors import ConfigError

    paths = [Path(r).resolve() for r in recordings]
    names = [p.name for p in paths]
    names = [f"{p.parent.name}-{p.name}" if names.count(p.name) > 1 else p.name for p in paths]
    seen: dict[str, str] = {}
    reserved = {n.lower() for n in RESERVED_NAMES}  # case-blind: fleet.CSV is fleet.csv on some file systems
    for r, name in zip(recordings, names):
        if name.lower() in reserved:
            raise ConfigError(f"{r}: a recording named {name} would write its outputs to OUT/{name}, the fleet "
                              f"report's own name; rename the recording's folder (or link it under another name)")
        if name in seen:
            raise ConfigError(f"{r} and {seen[name]} would both write to OUT/{name}; give each recording once")
        seen[name] = str(r)
    return names


def recording_of(folder) -> str | None:
    """The recording (its resolved path, as the report row has it) whose outputs ``folder``'s manifest holds;
    None without a readable manifest."""
    try:
        path = json.loads((Path(folder) / MANIFEST).read_text())["row"]["path"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return path if isinstance(path, str) else None


def check_recording_folder(folder, recording) -> None:
    """`OutputError` unless fleet may write ``recording``'s outputs into ``folder``: new (absent or empty), or
    holding fleet's own earlier outputs (every file listed in its `MANIFEST`) of that same recording. Another
    recording of the same name (``van1/drive`` in an earlier command, ``van2/drive`` now) is refused, not
    replaced; so is any file fleet did not write there (`radar_odom.outputs.check_output_folder`)."""
    from ..errors import OutputError
    from ..outputs import check_output_folder

    folder = Path(folder)
    if folder.is_symlink():
        raise OutputError(f"{folder}: is a link, which fleet did not make; kept: give -o another folder, or "
                          "remove the link")
    if not check_output_folder(folder, MANIFEST, "fleet"):
        return
    earlier = recording_of(folder)
    if earlier is None or Path(earlier).resolve() != Path(recording).resolve():
        raise OutputError(f"{folder}: holds fleet's outputs of another recording ({earlier or 'unknown'}), not of "
                          f"{recording}; kept: give -o another folder, or give both recordings in one command "
                          f"(each then gets its parent's name in front: docs/fleet.md)")


def check_fleet_outputs(recordings, names, out_dir) -> None:
    """Every refusal about where a fleet writes, before any work: `OutputError` where OUT is a recording, inside
    one or holds one (its outputs would be written among the inputs: ``fleet drives/drive -o drives``), or where
    a recording's folder ``OUT/<name>`` holds anything but fleet's own earlier outputs of that recording
    (`check_recording_folder`)."""
    from ..errors import OutputError

    out_dir = Path(out_dir)
    out = out_dir.resolve()
    for r in recordings:
        rec = Path(r).resolve()
        if rec == out or out in rec.parents:
            raise OutputError(f"-o {out_dir}: holds the recording {r}; outputs are never written among the "
                              f"inputs: give -o a folder outside every recording")
        if rec in out.parents:
            raise OutputError(f"-o {out_dir}: is inside the recording {r}; outputs are never written among the "
                              f"inputs: give -o a folder outside every recording")
    for r, name in zip(recordings, names):
        check_recording_folder(out_dir / name, r)
