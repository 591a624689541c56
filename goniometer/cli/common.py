"""What every ``gonio`` command shares: the one-line user error, exit codes, Ctrl-C handling,
progress bars and the parsers of common option values.

Command plugins (``models.commands``) import these; nothing below the application does.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """A user error the CLI reports as one line ``gonio: error: ...`` with exit status 2."""


class Interrupts:
    """Ctrl-C handling of the long commands (:func:`sigint_latch`)."""

    def __init__(self) -> None:
        self.hit = False
        self.deferring = False

    def handler(self, signum, frame) -> None:
        self.hit = True
        if not self.deferring:
            raise KeyboardInterrupt
        print("gonio: interrupt received; stopping once the kernel is compiled", file=sys.stderr)

    def check(self) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed since entry."""
        if self.hit:
            raise KeyboardInterrupt

    @contextlib.contextmanager
    def deferred(self):
        """Within the block Ctrl-C is only recorded; it is raised when the block ends."""
        self.deferring = True
        try:
            yield
        finally:
            self.deferring = False
        self.check()


@contextlib.contextmanager
def sigint_latch():
    """Yield an :class:`Interrupts`: SIGINT raises KeyboardInterrupt at once and is also latched.

    Python drops a KeyboardInterrupt raised while a finalizer runs, and one raised inside numba's
    compiler can leave it broken (a RuntimeError instead of a clean exit), so long commands compile
    inside ``deferred()`` and call ``check()`` at every progress report. Outside the main thread
    (no signal handlers there), or where SIGINT is ignored (a background job of a script), nothing
    is installed and ``check()`` never raises.
    """
    state = Interrupts()
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is signal.SIG_IGN):
        yield state
        return
    previous = signal.signal(signal.SIGINT, state.handler)
    try:
        yield state
    finally:
        signal.signal(signal.SIGINT, previous)


def incident_list(text: str) -> tuple[list[float], list[float] | None]:
    thetas: list[float] = []
    phis: list[float] = []
    any_phi = False
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        try:
            if ":" in part:
                t, p = part.split(":", 1)
                thetas.append(float(t))
                phis.append(float(p))
                any_phi = True
            else:
                thetas.append(float(part))
                phis.append(0.0)
        except ValueError:
            raise UsageError(f"--incident: {part!r} is not a number (expected e.g. 0,30,60 or 30:45)") from None
    if not thetas:
        raise UsageError("--incident: no incident angle given")
    return thetas, (phis if any_phi else None)


def resolution(text: str) -> tuple[int, int]:
    try:
        a, b = text.lower().split("x")
        return int(a), int(b)
    except ValueError:
        raise UsageError(f"--resolution: {text!r} is not of the form N_THETAxN_PHI (e.g. 90x360)") from None


def progress_bar(total: int, desc: str):
    from tqdm import tqdm
    return tqdm(total=total, desc=desc, unit="ray", unit_scale=True, file=sys.stderr,
                dynamic_ncols=True, disable=None, smoothing=0.1)
