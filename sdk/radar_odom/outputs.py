"""Output paths checked before the work that fills them: a refusal comes first, in one line, not after minutes."""
from __future__ import annotations

from .errors import OutputError


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
