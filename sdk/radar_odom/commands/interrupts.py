"""Ctrl-C and SIGTERM on the command line: the work so far kept, one line saying so, exit 130 / 143.

Ctrl-C raises Python's `KeyboardInterrupt` in the main thread. `sigterm_interrupts` makes SIGTERM (a service
manager's stop, ``kill``, a batch system's time limit, torchrun tearing a job down) do the same, as `Terminated`, for
the time a command runs, so that both unwind alike: ``finally`` blocks run, `run_sequence` writes the outputs so far
marked partial (`radar_odom.errors.RunInterrupted`), fleet lets its Ray workers go, train's and adapt's last saved
epoch stays for ``--resume``. `radar_odom.commands.cli.main` installs it around every command and turns the
interrupt into `interrupted_line` and `exit_status`; a command says what was kept through its ``interrupted``
default (``set_defaults(interrupted=fn)``, ``fn(args, exc) -> str``). Only the command line sets a handler: the
library never touches the process's signals.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading

SIGINT_STATUS = 128 + signal.SIGINT  # 130, as a shell reports a process Ctrl-C ended
SIGTERM_STATUS = 128 + signal.SIGTERM  # 143


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread where Ctrl-C's `KeyboardInterrupt` would be (`sigterm_interrupts`)."""


@contextlib.contextmanager
def sigterm_interrupts():
    """Within the block, SIGTERM raises `Terminated` in the main thread; the previous handler is put back after.
    A forked child that inherits the handler dies of SIGTERM as it would have. Off the main thread (where Python
    cannot set handlers) it changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    owner = os.getpid()

    def handler(signum, frame):
        if os.getpid() != owner:  # a forked child: SIGTERM's default, not this process's unwinding
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)
            return
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def terminated(exc: BaseException) -> bool:
    """True where ``exc`` is, or was raised for, a `Terminated` (SIGTERM) rather than Ctrl-C."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, Terminated):
            return True
        seen.add(id(exc))
        exc = getattr(exc, "cause", None) or exc.__cause__ or exc.__context__
    return False


def exit_status(exc: BaseException) -> int:
    """143 for SIGTERM, 130 for Ctrl-C (SIGINT): what a shell reports for a process the signal ended."""
    return SIGTERM_STATUS if terminated(exc) else SIGINT_STATUS


def interrupted_line(command: str, exc: BaseException, hint: str = "") -> str:
    """The one line an interrupted command prints: which signal, what ``exc`` says of the work kept (a
    `RunInterrupted`'s message, which starts "interrupted ..."), and the command's ``hint``."""
    sig = "SIGTERM" if terminated(exc) else "SIGINT"
    text = " ".join(str(exc).split())  # one line, whatever the message holds
    if text.startswith("interrupted"):
        text = f"interrupted ({sig}){text[len('interrupted'):]}"
    else:
        text = f"interrupted ({sig})"
    hint = " ".join(hint.split())
    return f"radar-odom {command}: {text}" + (f"; {hint}" if hint else "")


def command_hint(args, exc: BaseException) -> str:
    """The command's own word on what an interrupt kept (its ``interrupted`` default), or "" where it has none or
    cannot say (a hint that fails costs the hint, never the line)."""
    fn = getattr(args, "interrupted", None)
    if not callable(fn):
        return ""
    try:
        return str(fn(args, exc) or "")
    except Exception:  # noqa: BLE001 - the hint looks at files an interrupted command left: anything may be off
        return ""
