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
#: the help of every ``--threads`` option
THREADS_HELP = "numba threads; no effect on the results (default: all cores, NUMBA_NUM_THREADS)"


class UsageError(Exception):
    """A user error the CLI reports as one line ``gonio: error: ...`` with exit status 2."""


class Interrupts:
    """Ctrl-C handling of the long commands (:func:`sigint_latch`)."""

    def __init__(self) -> None:
        self.hit = False
        self.deferring = False
        self.finished = False

    def handler(self, signum, frame) -> None:
        if self.finished:
            return
        self.hit = True
        if not self.deferring:
            raise KeyboardInterrupt
        print("gonio: interrupt received; stopping once the kernel is compiled", file=sys.stderr)

    def check(self) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed since entry."""
        if self.hit:
            raise KeyboardInterrupt

    def finish(self) -> None:
        """From now on Ctrl-C is ignored: the result is safely written, and what remains
        (removing checkpoints) must not be reported as an interrupted run."""
        self.finished = True
        self.hit = False

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


def at_least_one(value: int, option: str, what: str) -> int:
    """``value`` if it is 1 or more, else a UsageError naming ``option`` and the allowed range."""
    if value < 1:
        raise UsageError(f"{option}: {value} is not allowed; {what} is 1 or more")
    return value


def resolution(text: str) -> tuple[int, int]:
    try:
        a, b = text.lower().split("x")
        return int(a), int(b)
    except ValueError:
        raise UsageError(f"--resolution: {text!r} is not of the form N_THETAxN_PHI (e.g. 90x360)") from None


class LineProgress:
    """Progress for a stderr that is not a terminal (a log file, a pipe, a batch job): one line
    ``DESC: 40% (4.00M/10.0M ray) 1.23M ray/s, ETA 00:05 [postfix]`` each time another tenth of
    ``total`` is done, and a last line at 100 %. The subset of tqdm's interface the commands use:
    ``update``, ``write``, ``set_postfix_str``, ``refresh``, ``close``, the ``n`` and ``total``
    attributes, and the context manager."""

    def __init__(self, total: int | None, desc: str, unit: str = "ray", file=None, step: float = 0.1,
                 clock=None, unit_scale: bool = True) -> None:
        import time
        self.total, self.desc, self.unit, self.n = total, desc, unit, 0
        self.unit_scale = unit_scale
        self.file = file if file is not None else sys.stderr
        self.step = step
        self.clock = clock or time.monotonic
        self.start = self.clock()
        self.postfix = ""
        self.printed = 0  # tenths printed so far
        self.closed = False

    def __enter__(self) -> "LineProgress":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n
        self.refresh()

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        self.postfix = s
        if refresh:
            self.refresh()

    def write(self, s: str, file=None) -> None:
        print(s, file=file if file is not None else self.file, flush=True)

    def refresh(self) -> None:
        if not self.total or self.closed:
            return
        reached = int(min(self.n / self.total, 1.0) / self.step + 1e-9)
        if reached > self.printed:
            self.printed = reached
            self.file.write(self.line() + "\n")
            self.file.flush()

    def line(self) -> str:
        from tqdm import tqdm
        size = tqdm.format_sizeof if self.unit_scale else (lambda x: f"{x:.3g}" if x != int(x) else f"{int(x)}")
        elapsed = max(self.clock() - self.start, 1e-9)
        rate = self.n / elapsed
        frac = self.n / self.total if self.total else 0.0
        eta = tqdm.format_interval((self.total - self.n) / rate) if rate > 0 and self.total else "?"
        text = (f"{self.desc}: {100 * frac:3.0f}% ({size(self.n)}/{size(self.total or 0)} {self.unit}) "
                f"{size(rate)} {self.unit}/s, elapsed {tqdm.format_interval(elapsed)}, ETA {eta}")
        return text + (f" [{self.postfix}]" if self.postfix else "")

    def close(self) -> None:
        self.closed = True


def progress_bar(total: int | None, desc: str, unit: str = "ray", **tqdm_options):
    """A tqdm bar on a terminal; elsewhere a :class:`LineProgress` (a line every 10 % with the rate
    and the time left), so that logs of batch runs show progress too."""
    if not sys.stderr.isatty():
        return LineProgress(total, desc, unit, unit_scale=tqdm_options.get("unit_scale", True))
    from tqdm import tqdm
    options = {"unit_scale": True, "dynamic_ncols": True, "smoothing": 0.1, **tqdm_options}
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, **options)
