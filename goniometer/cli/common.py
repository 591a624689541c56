"""What every ``gonio`` command shares: the one-line user error, exit codes, Ctrl-C handling,
progress bars and the parsers of common option values.

Command plugins (``models.commands``) import these; nothing below the application does.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from typing import Any, Callable

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130
#: the help of every ``--threads`` option
THREADS_HELP = "numba threads; no effect on the results (default: all cores, NUMBA_NUM_THREADS)"
#: the help of every ``--overwrite`` option (docs/outputs.md)
OVERWRITE_HELP = ("replace an existing finished output (default: refuse, saying what it holds; "
                  "docs/outputs.md)")


class UsageError(Exception):
    """A user error the CLI reports as one line ``gonio: error: ...`` with exit status 2."""


@contextlib.contextmanager
def usage_errors(*kinds: type[BaseException], prefix: str | None = None):
    """Turn the library errors ``kinds`` raised in the block into a :class:`UsageError` (one line,
    exit 2). ``prefix`` (a file or option name) is put in front of a message that does not start
    with it already."""
    try:
        yield
    except kinds as e:
        msg = str(e)
        if prefix and not msg.startswith(prefix):
            msg = f"{prefix}: {msg}"
        raise UsageError(msg) from None


def add_overwrite(parser) -> None:
    """Add ``--overwrite`` (docs/outputs.md) to a command's parser."""
    parser.add_argument("--overwrite", action="store_true", help=OVERWRITE_HELP)


#: the default a material file's ``[simulation]`` table sets, in help texts
FROM_FILE = "the file's [simulation] table, else "


def add_device(parser) -> None:
    """Add ``--device`` (docs/gpu.md) to a command's parser (default: cpu; a material file's
    ``[simulation]`` table has no device: where the paths run is the command's choice)."""
    from goniometer.run.settings import DEVICES
    parser.add_argument("--device", choices=DEVICES,
                        help="where the paths are traced: cpu (numba threads) or cuda (an NVIDIA GPU through "
                             "numba-cuda, pip install 'goniometer[cuda]'; the same transport, other bits: "
                             f"docs/gpu.md) (default: cpu)")


def add_polarized(parser) -> None:
    """Add ``--polarized`` (docs/polarization.md) to a command's parser."""
    parser.add_argument("--polarized", action="store_true", default=None,
                        help="trace polarized light: every path carries Mueller matrices and the file holds each "
                             "cell's Mueller matrix beside its intensity (docs/polarization.md) "
                             f"(default: {FROM_FILE}scalar light)")


def add_spectral(parser) -> None:
    """Add ``--spectral`` and ``--wavelength-bins`` (docs/spectral.md) to a command's parser."""
    parser.add_argument("--spectral", action="store_true", default=None,
                        help="trace wavelengths instead of RGB channels: every per-channel quantity gets one entry "
                             "per wavelength bin over 360-830 nm, --rays paths per bin (docs/spectral.md) "
                             f"(default: {FROM_FILE}RGB)")
    parser.add_argument("--wavelength-bins", dest="wavelength_bins", type=whole_number, metavar="N",
                        help=f"wavelength bins of a spectral run, a multiple of 3 (default: {FROM_FILE}30, "
                             f"15.7 nm each)")


def output_path(path, *, inputs=(), overwrite: bool = False, option: str = "--out", directory: bool = False,
                marker: str | None = None):
    """:func:`goniometer.files.outputs.check_output` with its refusal as a :class:`UsageError`; returns the
    path. Also refuses a file whose directory does not exist or cannot be written."""
    from pathlib import Path

    from goniometer.files import outputs
    _check_ancestors(Path(path), option)
    with usage_errors(outputs.OutputError):
        out = outputs.check_output(path, inputs=inputs, overwrite=overwrite, option=option, directory=directory,
                                   marker=marker)
    if not directory:
        from goniometer.files import slices as store
        with usage_errors(store.StoreError, prefix=option):
            store.check_writable(out)
    return Path(out)


def _check_ancestors(path, option: str) -> None:
    """A :class:`UsageError` when the nearest existing directory above ``path`` is a file
    (``--out m.h5/x.h5``: ``m.h5 is a file, not a directory``, not "does not exist")."""
    from goniometer.files.outputs import describe_existing
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise UsageError(f"{option}: {path}: {parent} is a file ({describe_existing(parent)}), not a directory")
            return


def thread_number(text: str) -> int:
    """An argparse ``type`` for ``--threads``: a whole number in [1, NUMBA_NUM_THREADS] (what the
    machine's numba can run; :func:`goniometer.kernel.tracer.check_device` checks the same for the
    library)."""
    import argparse

    import numba
    n = whole_number(text)
    top = numba.config.NUMBA_NUM_THREADS
    if not 1 <= n <= top:
        raise argparse.ArgumentTypeError(f"{n} is outside [1, {top}] (the numba threads of this machine, "
                                         f"NUMBA_NUM_THREADS)")
    return n


def whole_number(text: str) -> int:
    """An argparse ``type`` for counts: an integer, also written as ``1e5`` or ``2.5e6`` when that is
    a whole number."""
    import argparse
    import math
    try:
        return int(text)
    except ValueError:
        pass
    try:
        x = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (e.g. 100000 or 1e5)") from None
    if not math.isfinite(x) or x != int(x):
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number (e.g. 100000 or 1e5)")
    return int(x)


class Interrupts:
    """Ctrl-C handling of the long commands (:func:`sigint_latch`)."""

    def __init__(self) -> None:
        self.hit = False
        self.deferring = False
        self.finished = False
        #: what a Ctrl-C inside :meth:`deferred` waits for (printed when it arrives)
        self.note = "stopping once the kernel is compiled"

    def handler(self, signum, frame) -> None:
        if self.finished:
            return
        self.hit = True
        if not self.deferring:
            raise KeyboardInterrupt
        if self.note:
            print(f"gonio: interrupt received; {self.note}", file=sys.stderr)

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
    def writing(self):
        """The final write of a command's output: within the block Ctrl-C is only recorded, and the
        ``commit`` the block yields (for :func:`goniometer.atomic.atomic_path`) raises
        KeyboardInterrupt if it was pressed before the file took its name, so the output is not
        written and the run stays resumable. Once the file has its name the run is over: a
        Ctrl-C after that is ignored (:meth:`finish`)."""
        self.deferring, note, self.note = True, self.note, ""
        try:
            yield self.check
        finally:
            self.deferring, self.note = False, note
        self.finish()

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


#: a first cold compile of one kernel variant takes about this long on 2 cores (measured: 40-55 s for
#: the first variant with its shared functions, 10-20 s for each further one); only the estimate in
#: the notice below uses it
COMPILE_FIRST_S = 45.0
COMPILE_MORE_S = 15.0
#: a warm-up that takes longer than this many seconds is announced (compiling, or loading from the cache)
COMPILE_NOTICE_AFTER_S = 1.0


class CompileWatch:
    """Counts what numba compiles while it is installed (the ``numba:compile`` event, which numba
    fires for a function it compiles and not for one it loads from its on-disk cache; numba-cuda's
    own event too, when numba-cuda is loaded), and whether every compiled function is cached on
    disk (then a later run loads it)."""

    def __init__(self) -> None:
        self.compiled = 0
        self.uncached = 0

    @contextlib.contextmanager
    def installed(self):
        import numba.core.event as ev
        modules = [ev] + [m for m in (sys.modules.get("numba.cuda.core.event"),)
                          if m is not None and hasattr(m, "register") and hasattr(m, "Listener")]
        # each event module takes only its own kind (numba-cuda refuses a "numba:" kind)
        kinds = ["numba:compile" if m is ev else "numba-cuda:compile" for m in modules]
        listeners = [self._listener(m) for m in modules]
        for m, kind, listener in zip(modules, kinds, listeners):
            m.register(kind, listener)
        try:
            yield self
        finally:
            for m, kind, listener in zip(modules, kinds, listeners):
                m.unregister(kind, listener)

    def _listener(self, module):
        watch = self

        class Listener(module.Listener):
            def on_start(self, event) -> None:
                watch.started(event.data.get("dispatcher") if isinstance(event.data, dict) else None)

            def on_end(self, event) -> None:
                pass

        return Listener()

    def started(self, dispatcher) -> None:
        """One function is being compiled (``dispatcher``, numba's, or None if unknown). numba's own
        implementations (``np.zeros`` and the like) have no cache of their own: they are compiled
        into their caller, and cached with it."""
        self.compiled += 1
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", None)
        if dispatcher is None or module is None or module.split(".")[0] == "numba":
            return
        if getattr(getattr(dispatcher, "_cache", None), "cache_path", None) is None:
            self.uncached += 1


def compile_kernels(warm_up: Callable[[], float], variants: int = 1, file=None, clock=None) -> float:
    """Run ``warm_up()`` (which compiles or loads the kernels a run needs) and return its seconds.

    A warm-up done within :data:`COMPILE_NOTICE_AFTER_S` shows nothing. A longer one says what it
    is doing, as measured by :class:`CompileWatch`: ``loading compiled kernels`` while numba only
    loads from its on-disk cache, ``compiling kernels (first run only, about N s)`` once it
    actually compiles (without "first run only" when what it compiles has no on-disk cache), with
    the elapsed time (on a terminal one line that counts up; in a log a line every 15 s), and a
    last line ``loaded compiled kernels in T s`` or ``compiled kernels in T s``. The warm-up runs
    in a worker thread so that the main thread can report; Ctrl-C is the caller's (inside
    :meth:`Interrupts.deferred`, it takes effect once compiling is over). The seconds are the
    run's ``compile_s``, never tracing time (``docs/architecture.md``, honest first runs)."""
    import time
    clock = clock or time.monotonic
    file = file if file is not None else sys.stderr
    box: dict[str, Any] = {}
    watch = CompileWatch()

    def work() -> None:
        try:
            box["s"] = warm_up()
        except BaseException as e:  # re-raised in the caller's thread
            box["error"] = e

    with watch.installed():
        worker = threading.Thread(target=work, name="gonio-compile", daemon=True)
        t0 = clock()
        worker.start()
        worker.join(COMPILE_NOTICE_AFTER_S)
        if worker.is_alive():
            _report_warm_up(worker, watch, t0, clock, file,
                            COMPILE_FIRST_S + COMPILE_MORE_S * max(0, variants - 1))
        else:
            worker.join()
    if "error" in box:
        raise box["error"]
    return box["s"]


def _report_warm_up(worker: threading.Thread, watch: CompileWatch, t0: float, clock, file, estimate: float) -> None:
    """The words of :func:`compile_kernels` while ``worker`` runs, and its last line."""
    tty = file.isatty() if hasattr(file, "isatty") else False

    def head() -> str:
        if not watch.compiled:
            return "loading compiled kernels"
        if watch.uncached:
            return "compiling kernels (not cached on disk: every run compiles them)"
        return f"compiling kernels (first run only, about {estimate:.0f} s)"

    shown, last = "", clock()
    while True:
        now, text = clock(), head()
        if tty:
            file.write(f"\r\033[K{text}: {now - t0:4.0f} s elapsed")
            file.flush()
        elif text != shown:
            print(f"{text} ...", file=file, flush=True)
            last = now
        elif now - last >= 15.0:
            print(f"  {now - t0:.0f} s elapsed", file=file, flush=True)
            last = now
        shown = text
        if not worker.is_alive():
            break
        worker.join(0.25 if tty else 1.0)
    elapsed = clock() - t0
    if tty:
        file.write("\r\033[K")
    if watch.compiled:
        print(f"compiled kernels in {elapsed:.1f} s" + ("" if watch.uncached else " (cached for later runs)"),
              file=file, flush=True)
    else:
        print(f"loaded compiled kernels in {elapsed:.1f} s", file=file, flush=True)


class LineProgress:
    """Progress for a stderr that is not a terminal (a log file, a pipe, a batch job): one line
    ``DESC: 40% (4.00M/10.0M ray) 1.23M ray/s, ETA 00:05 [postfix]`` each time another tenth of
    ``total`` is done, or :data:`every_s` seconds after the last line, whichever comes first, and a
    last line at 100 %. The subset of tqdm's interface the commands use: ``update``, ``write``,
    ``set_postfix_str``, ``refresh``, ``close``, the ``n`` and ``total`` attributes, and the context
    manager; and :meth:`skip` (work found done, e.g. checkpoints, which the rate leaves out)."""

    def __init__(self, total: int | None, desc: str, unit: str = "ray", file=None, step: float = 0.1,
                 clock=None, unit_scale: bool = True, every_s: float = 30.0) -> None:
        import time
        self.total, self.desc, self.unit, self.n = total, desc, unit, 0
        self.unit_scale = unit_scale
        self.file = file if file is not None else sys.stderr
        self.step = step
        self.every_s = every_s
        self.clock = clock or time.monotonic
        self.start = self.clock()
        self.last_line = self.start
        self.skipped = 0  # work found done, left out of the rate
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

    def skip(self, n: int) -> None:
        """Count ``n`` units as done without having done them now (the rate and the time left
        are of the work this run does)."""
        self.n += n
        self.skipped += n
        self.start = self.clock()
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
        now = self.clock()
        if reached > self.printed or (self.n < self.total and now - self.last_line >= self.every_s):
            self.printed = max(self.printed, reached)
            self.last_line = now
            self.file.write(self.line() + "\n")
            self.file.flush()

    def line(self) -> str:
        from tqdm import tqdm
        size = tqdm.format_sizeof if self.unit_scale else (lambda x: f"{x:.3g}" if x != int(x) else f"{int(x)}")
        elapsed = max(self.clock() - self.start, 1e-9)
        rate = (self.n - self.skipped) / elapsed
        frac = self.n / self.total if self.total else 0.0
        eta = tqdm.format_interval((self.total - self.n) / rate) if rate > 0 and self.total else "?"
        text = (f"{self.desc}: {100 * frac:3.0f}% ({size(self.n)}/{size(self.total or 0)} {self.unit}) "
                f"{size(rate)} {self.unit}/s, elapsed {tqdm.format_interval(elapsed)}, ETA {eta}")
        return text + (f" [{self.postfix}]" if self.postfix else "")

    def close(self) -> None:
        self.closed = True


def skip_progress(bar, n: int) -> None:
    """Count ``n`` units of ``bar`` as done before this run (resumed from checkpoints), so that its
    rate and time left are of the work this run does: :meth:`LineProgress.skip`, or for a tqdm bar
    its ``initial`` count."""
    if hasattr(bar, "skip"):
        bar.skip(n)
        return
    bar.update(n)
    bar.initial = bar.n
    bar.last_print_n = bar.n
    bar.start_t = bar.last_print_t = bar._time()
    bar.refresh()


class ResumeAware:
    """A progress callback for :func:`goniometer.run.loop.run_incidents` and the like, which report the
    rays of finished work they load (checkpoints) through ``progress`` too: those, announced by
    :meth:`resumed`, go to :func:`skip_progress`; the rest updates the bar."""

    def __init__(self, bar, check: Callable[[], None] | None = None) -> None:
        self.bar, self.check, self.pending = bar, check, 0

    def resumed(self, n: int) -> None:
        self.pending += n

    def __call__(self, n: int) -> None:
        if self.check is not None:
            self.check()
        if self.pending > 0:
            k = min(n, self.pending)
            self.pending -= k
            skip_progress(self.bar, k)
            n -= k
        if n:
            self.bar.update(n)


def progress_bar(total: int | None, desc: str, unit: str = "ray", **tqdm_options):
    """A tqdm bar on a terminal; elsewhere a :class:`LineProgress` (a line every 10 % with the rate
    and the time left), so that logs of batch runs show progress too."""
    if not sys.stderr.isatty():
        return LineProgress(total, desc, unit, unit_scale=tqdm_options.get("unit_scale", True))
    from tqdm import tqdm
    options = {"unit_scale": True, "dynamic_ncols": True, "smoothing": 0.1, **tqdm_options}
    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, **options)
