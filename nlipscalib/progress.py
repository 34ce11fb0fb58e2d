"""Progress bars and logging for long commands: one switch for the whole ``nlips`` run.

Bars (tqdm) go to stderr only when it is a terminal and ``--no-progress`` was not given, so log files
and CI output never fill with carriage-return bars. ``--log-file`` copies every log line to a file.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

_enabled = True


def configure(*, progress: bool = True, verbose: bool = False, log_file: str | Path | None = None) -> None:
    """Set up logging (stderr, plus ``log_file`` when given) and the global progress switch.

    Handlers already on the root logger (an embedding application's, pytest's) are kept; only the
    file handler this function added before is replaced.
    """
    global _enabled
    _enabled = progress
    root = logging.getLogger()
    root.setLevel(logging.DEBUG if verbose else logging.INFO)
    for handler in [h for h in root.handlers if getattr(h, _OURS, False)]:
        root.removeHandler(handler)
        handler.close()
    if not root.handlers:
        _add(root, logging.StreamHandler(sys.stderr), "%(levelname)s %(message)s")
    if log_file:
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        _add(root, logging.FileHandler(log_file, encoding="utf-8"), "%(asctime)s %(levelname)s %(name)s: %(message)s")


_OURS = "_nlips_handler"


def file_log(level: int, message: str) -> None:
    """Record ``message`` in the log file only (for lines already printed on the terminal)."""
    record = logging.LogRecord("nlipscalib", level, __file__, 0, message, None, None)
    for handler in logging.getLogger().handlers:
        if getattr(handler, _OURS, False) and isinstance(handler, logging.FileHandler):
            handler.handle(record)


def _add(root: logging.Logger, handler: logging.Handler, fmt: str) -> None:
    handler.setFormatter(logging.Formatter(fmt))
    setattr(handler, _OURS, True)
    root.addHandler(handler)


def bars_enabled(requested: bool = True) -> bool:
    """Whether a bar would be drawn: requested, not switched off globally, and stderr is a terminal."""
    return bool(requested and _enabled and sys.stderr.isatty())


def progress_bar(total: int | None = None, *, enabled: bool = True, **kwargs):
    """A tqdm bar (usable as a context manager), silent unless :func:`bars_enabled`.

    Parameters
    ----------
    total : number of steps (None when unknown)
    enabled : the caller's own switch (e.g. a function's ``progress`` argument)
    kwargs : passed to tqdm (desc, unit, initial, ...)
    """
    from tqdm.auto import tqdm

    return tqdm(total=total, disable=not bars_enabled(enabled), **kwargs)


def track(iterable, *, enabled: bool = True, **kwargs):
    """Iterate with a progress bar (see :func:`progress_bar`)."""
    from tqdm.auto import tqdm

    return tqdm(iterable, disable=not bars_enabled(enabled), **kwargs)


class working:  # noqa: N801 - used like a function: ``with working("rendering"):``
    """Show that an opaque step (one long library call) is alive: a ticking elapsed-time line.

    On a terminal: ``rendering: 00:12`` refreshed twice a second. Otherwise one log line when the step
    starts and one with its duration when it ends.
    """

    def __init__(self, desc: str, *, enabled: bool = True):
        self.desc, self.enabled = desc, bars_enabled(enabled)

    def __enter__(self):
        import threading
        import time

        self.t0 = time.perf_counter()
        if not self.enabled:
            logging.getLogger("nlipscalib").info("%s ...", self.desc)
            return self
        from tqdm.auto import tqdm

        self.bar = tqdm(total=None, desc=self.desc, bar_format="{desc}: {elapsed}")
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._tick, daemon=True)
        self._thread.start()
        return self

    def _tick(self) -> None:
        while not self._stop.wait(0.5):
            self.bar.refresh()

    def __exit__(self, exc_type, exc, tb):
        import time

        seconds = time.perf_counter() - self.t0
        if self.enabled:
            self._stop.set()
            self._thread.join()
            self.bar.close()
        elif exc_type is None:
            logging.getLogger("nlipscalib").info("%s done in %.1f s", self.desc, seconds)
        return False
