"""Progress bars for long command-line work: tqdm when the ``cli`` extra is installed."""
from __future__ import annotations


def progress(iterable=None, total=None, desc=None, unit="it", disable=False):
    """Wrap an iterable in a tqdm bar on stderr; a no-op wrapper when tqdm is not installed."""
    try:
        from tqdm.auto import tqdm
    except ImportError:  # the runtime API must work with the three core dependencies only
        return iterable if iterable is not None else _NullBar()
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=disable, dynamic_ncols=True)


class _NullBar:
    def update(self, n=1):
        pass

    def set_postfix(self, *a, **k):
        pass

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False
