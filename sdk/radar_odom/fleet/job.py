"""One recording of a fleet: `radar-odom run`'s own `run_sequence` into a hidden folder, its report row and
manifest written there, then the folder renamed into place. No Ray here: this is what a worker calls."""
from __future__ import annotations

import re
import shutil
import uuid
from pathlib import Path

from .manifest import MANIFEST, check_recording_folder, write_manifest


def _hidden(out_root: Path, name: str, kind: str) -> list[Path]:
    """``out_root/.<name>.<kind>-<hex>``: the hidden folders fleet itself makes for ``name`` (tmp, old)."""
    pattern = re.compile(rf"\.{re.escape(name)}\.{kind}-[0-9a-f]+")
    return [p for p in out_root.iterdir() if pattern.fullmatch(p.name)] if out_root.is_dir() else []


def process_recording(model, recording, out_root, name: str, options: dict, key: str) -> dict:
    """Run ``model`` (an `OnnxModel` a worker keeps across recordings, or a path) over ``recording`` with
    `run_sequence`'s keyword ``options`` (`radar_odom.commands.run.sequence_options`: what `radar-odom run`
    passes), publish the outputs as ``out_root/name`` and return the recording's report row.

    Atomic: everything is written into ``out_root/.name.tmp-*`` (same file system), the manifest
    (`manifest.write_manifest`, with ``key``) last, and only then renamed to ``out_root/name``; an error
    removes the hidden folder and propagates, leaving an earlier complete ``out_root/name`` untouched."""
    import time
    import warnings

    from ..errors import GroundTruthWarning
    from ..runs.run_sequence import run_sequence
    from .report import result_row

    out_root = Path(out_root)
    check_recording_folder(out_root / name, recording)  # before the work (the command checked it too)
    # what an attempt killed with its worker left (one attempt per recording runs at a time: none is live): a
    # temporary folder is fleet's alone; an earlier folder set aside loses only what its manifest lists
    for stale in _hidden(out_root, name, "tmp"):
        shutil.rmtree(stale, ignore_errors=True)
    for stale in _hidden(out_root, name, "old"):
        _discard(stale)
    tmp = out_root / f".{name}.tmp-{uuid.uuid4().hex[:8]}"
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", GroundTruthWarning)
            result = run_sequence(recording, model, tmp, show_progress=False, **options)
        row = result_row(name, recording, result)
        # a worker's stderr is not the user's: what `run` would print as warnings goes into the row
        row["warnings"] = " | ".join([*(str(w.message).splitlines()[0] for w in caught), *result.problems])
        row["seconds"] = time.perf_counter() - t0  # before the manifest: its digests are a few ms of a long run
        write_manifest(tmp, key, row)
        publish(tmp, out_root / name)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return row


def publish(tmp, final) -> None:
    """Rename the finished folder ``tmp`` to ``final``; an existing ``final`` (fleet's own earlier outputs of
    the same recording, outdated) is first renamed aside and its listed files removed after, so ``final`` is
    never a half-written folder. `OutputError`, ``final`` untouched, where it holds anything else: a file fleet
    did not write, another recording's outputs (`manifest.check_recording_folder`, the recording read from
    ``tmp``'s manifest)."""
    from .manifest import recording_of

    tmp, final = Path(tmp), Path(final)
    old = None
    if final.exists() or final.is_symlink():
        check_recording_folder(final, recording_of(tmp) or "")
        old = final.with_name(f".{final.name}.old-{uuid.uuid4().hex[:8]}")
        final.rename(old)
    tmp.rename(final)
    if old is not None:
        _discard(old)


def _discard(folder: Path) -> None:
    """Remove fleet's own earlier outputs set aside in ``folder`` (the files its manifest lists, the manifest,
    then the folder if that left it empty); anything else stays where it is."""
    from ..outputs import remove_own_outputs

    remove_own_outputs(folder, MANIFEST, keep_manifest=False)
    try:
        folder.rmdir()
    except OSError:
        pass


def one_line(exc: BaseException) -> str:
    """A failure's reason in one line: a radar-odom error's own message, else the type and the first line."""
    from ..errors import RadarOdomError

    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return text if isinstance(exc, RadarOdomError) and text else f"{type(exc).__name__}: {text}".rstrip(": ")
