"""Output paths checked before the work that fills them: a refusal comes first, in one line, not after minutes.

Output folders a command fills and, on a later run, replaces (`check_output_folder`) follow one rule: a
command writes into a folder only where it is new (absent or empty) or holds that command's own earlier
outputs, recognised by the manifest it wrote there (a JSON file whose ``files`` names every file it wrote,
relative to the folder). Anything else there stops the command, in one line, before any work; replacing
removes only the files the manifest lists (`remove_own_outputs`), never a file the command did not write.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from .errors import OutputError

SHOWN = 3  # foreign files named in a refusal


def check_output_path(out, flag: str = "-o") -> None:
    """`OutputError` before the work (an export: minutes of tracing and verifying; an adaptation: much longer)
    where the file ``out`` cannot be written: a folder in its place, a parent that cannot be created (a file
    on its path) or is not writable (``-o /proc/m.onnx`` raised FileNotFoundError from mkstemp after the whole
    export). ``flag`` names the option in the message."""
    import tempfile
    from pathlib import Path

    out = Path(out)
    if out.is_dir():
        raise OutputError(f"{out}: is a folder; give {flag} the file to write")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create its folder {out.parent} ({exc.strerror or exc}); give "
                          f"{flag} a writable place") from None
    try:  # the export writes a temporary file beside the output first: try that now (os.access is not
        # enough: root may "write" /proc, which takes no new files)
        with tempfile.TemporaryFile(prefix=f".{out.name}.", suffix=".probe", dir=out.parent):
            pass
    except OSError as exc:
        raise OutputError(f"{out}: cannot write in its folder {out.parent} ({exc.strerror or exc}); give "
                          f"{flag} a writable place") from None


def manifest_files(folder, manifest: str) -> set[str] | None:
    """The files (relative POSIX paths) that the manifest ``folder/manifest`` lists as its command's own (its
    ``files``: a list, or a mapping keyed by path), or None where there is no readable manifest."""
    try:
        data = json.loads((Path(folder) / manifest).read_text())
    except (OSError, ValueError):  # absent, unreadable, half-written or edited into something else
        return None
    files = data.get("files") if isinstance(data, dict) else None
    if isinstance(files, dict):
        files = list(files)
    if not isinstance(files, list) or not all(isinstance(f, str) for f in files):
        return None
    return set(files)


def foreign_files(folder, manifest: str, names=None) -> list[str]:
    """The files in ``folder`` (relative POSIX paths, sorted) that its manifest does not list: every file and
    link below it (links are not followed), or only those of ``names`` (top-level entries) that exist. Empty
    folders hold nothing and are not listed; the manifest itself is its command's."""
    folder = Path(folder)
    own = manifest_files(folder, manifest) or set()
    if names is not None:
        return sorted(n for n in names if n != manifest and n not in own
                      and ((folder / n).exists() or (folder / n).is_symlink()))
    return [f for f in files_below(folder) if f != manifest and f not in own]


def files_below(folder) -> list[str]:
    """Every file and link below ``folder`` (relative POSIX paths, sorted; links are not followed)."""
    found = []
    for root, dirs, files in os.walk(folder):  # followlinks=False: a link to a folder is one entry
        rel = Path(root).relative_to(folder)
        found += [(rel / d).as_posix() for d in dirs if os.path.islink(os.path.join(root, d))]
        found += [(rel / f).as_posix() for f in files]
    return sorted(found)


def check_output_folder(folder, manifest: str, command: str, flag: str = "-o") -> bool:
    """Before any work: may ``command`` write into ``folder``? False where it is new (absent, or an empty folder),
    True where it holds ``command``'s own earlier outputs only (every file listed by ``folder/manifest``, which
    a later run replaces: `remove_own_outputs`); `OutputError` in one line otherwise (a file in its place, or
    any file the manifest does not list: the user's, another command's, an input)."""
    folder = Path(folder)
    if not folder.exists() and not folder.is_symlink():
        return False
    if not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder; give {flag} a new folder (or an earlier "
                          f"radar-odom {command}'s)")
    foreign = foreign_files(folder, manifest)
    if foreign:
        shown = ", ".join(foreign[:SHOWN]) + (f" and {len(foreign) - SHOWN} more" if len(foreign) > SHOWN else "")
        raise OutputError(f"{folder}: holds {len(foreign)} file(s) radar-odom {command} did not write ({shown}); it "
                          f"writes only into a new folder or one holding its own earlier outputs (listed in its "
                          f"{manifest}), so nothing was touched: give {flag} another folder, or move those files")
    return (folder / manifest).is_file()


def remove_own_outputs(folder, manifest: str, keep_manifest: bool = True) -> None:
    """Remove the files that ``folder/manifest`` lists (its command's earlier outputs, about to be replaced) and
    the folders they leave empty; a file it does not list stays, and so does its folder. The manifest goes
    too unless ``keep_manifest``."""
    folder = Path(folder)
    own = manifest_files(folder, manifest) or set()
    parents = set()
    for rel in own:
        if ".." in Path(rel).parts or Path(rel).is_absolute():
            continue  # an edited manifest naming a path outside its folder: never followed
        path = folder / rel
        inside = [p for p in path.parents if folder in p.parents]
        if any(p.is_symlink() for p in inside):
            continue  # through a link to another folder: not a file this command wrote here
        if path.is_symlink() or path.is_file():
            path.unlink()
        parents.update(inside)
    if not keep_manifest:
        (folder / manifest).unlink(missing_ok=True)
    for d in sorted(parents, key=lambda p: len(p.parts), reverse=True):  # deepest first
        try:
            d.rmdir()  # only an empty one
        except OSError:
            pass


def write_folder_manifest(folder, manifest: str, command: str, files=None, **fields) -> Path:
    """``folder/manifest``: ``command``, ``files`` (default: every file now below ``folder``, the manifest
    left out) and any other ``fields``, written atomically (a reader never sees half of it)."""
    folder = Path(folder)
    path, tmp = folder / manifest, folder / f".{manifest}.tmp"
    if files is None:
        files = [f for f in files_below(folder) if f not in (manifest, tmp.name)]
    tmp.write_text(json.dumps({"command": command, "files": sorted(files), **fields}, indent=1))
    tmp.replace(path)
    return path
