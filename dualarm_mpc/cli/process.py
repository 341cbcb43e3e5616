"""Process plumbing of the command line: exit codes, stop signals (SIGINT, SIGTERM, SIGHUP) and
the thread a long phase runs on so a signal reaches the main thread at once, heartbeats so no
phase is silent, and standard streams whose reader may go."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Callable

HEARTBEAT_S = 15.0  # seconds of a phase without a line before it says it is still going on


OK, BAD_INPUT, CONFLICT, FAILED = 0, 2, 3, 4  # exit codes; a stop signal: 128 + its number


# Each stops a run as Ctrl-C does: the work so far is written, marked partial.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# A stop signal this soon after the first is the same stop sent again (to the process group, as
# ``timeout`` and a shell's Ctrl-C do, or a key pressed twice): it must not cost what is written.
SAME_STOP_S = 1.0


received: list[int] = []  # the stop signals received by this run, first first
written: list[str] = []  # the outputs this run has written whole, first first


def outputs_left(asked: list[str]) -> str:
    """For the line of a stop that came while outputs were being written: which of ``asked``
    were written whole and which not ("" where none was asked)."""
    done = [path for path in asked if path in written]
    left = [path for path in asked if path not in written]
    said = ([f"wrote {', '.join(done)}"] if done else []) + \
        ([f"not written: {', '.join(left)}"] if left else [])
    return "".join(f"; {part}" for part in said)


class Abandoned(KeyboardInterrupt):
    """A signal stopped a phase that has nothing to keep; its thread still runs."""


def interruptible(work, stop=None, tick=lambda: None):
    """``work()`` on a thread, so that a stop signal (SIGINT, SIGTERM, SIGHUP: a
    ``KeyboardInterrupt`` here) reaches the main thread at once (a HiGHS run holds it until it
    returns). With ``stop`` (a ``solver.Interrupt``) the signal stops the solves and ``work``
    returns what it has; without, ``work`` has nothing to keep and is left to run
    (:class:`Abandoned`: the process ends without waiting for it). ``tick()`` runs every
    0.1 s."""
    out: dict = {}
    done = threading.Event()  # not Thread.join: a join cut short by a signal can lose the thread

    def run() -> None:
        try:
            out["value"] = work()
        except BaseException as err:  # re-raised on the main thread
            out["error"] = err
        finally:
            done.set()

    threading.Thread(target=run, daemon=True).start()
    try:
        while not done.wait(0.1):
            tick()
    except KeyboardInterrupt:
        if stop is None:
            raise Abandoned from None
        stop.set()
        print(f"interrupted by {signal_name()}: stopping the solver", file=sys.stderr,
              flush=True)
        try:
            done.wait()
        except KeyboardInterrupt:  # a later signal: do not wait for the solver to stop
            raise Abandoned from None
    if "error" in out:
        raise out["error"]
    return out["value"]


def heartbeat(what: str | Callable[[], str]):
    """A ``tick`` that says ``what`` (or what ``what()`` says now) is still going on every
    ``HEARTBEAT_S``: no phase is silent for long."""
    start = said = time.perf_counter()

    def tick() -> None:
        nonlocal said
        now = time.perf_counter()
        if now - said >= HEARTBEAT_S:
            print(f"{what() if callable(what) else what}: {now - start:.0f} s so far",
                  flush=True)
            said = now

    return tick


def stopped() -> int:
    """The exit code of a run a signal stopped: 128 + the signal's number (130 for Ctrl-C)."""
    return 128 + (received[0] if received else signal.SIGINT)


def signal_name() -> str:
    return signal.Signals(stopped() - 128).name


@contextlib.contextmanager
def stop_signals():
    """SIGTERM and SIGHUP stop the run as SIGINT does: a ``KeyboardInterrupt`` on the main
    thread, the signal noted for the exit code. A repeat within ``SAME_STOP_S`` of the first
    is noted only."""
    first: list[float] = []

    def stop(signum: int, frame) -> None:
        now = time.monotonic()
        received.append(signum)
        if first and now - first[0] < SAME_STOP_S:
            return
        first[:] = [now]
        raise KeyboardInterrupt

    received.clear()
    written.clear()
    before = {s: signal.signal(s, stop) for s in STOP_SIGNALS}
    try:
        yield
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)


class _Sturdy:
    """A standard stream whose reader may go (``| head -1``; the terminal, with SIGHUP): once a
    write fails it points at /dev/null and the run goes on to write its files (the recipe of
    Python's ``signal`` docs for BrokenPipeError)."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except OSError:
            self._lost()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except OSError:
            self._lost()

    def _lost(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # ValueError: no file descriptor
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


@contextlib.contextmanager
def sturdy_streams():
    saved = sys.stdout, sys.stderr
    for fd in (1, 2):  # started closed (``>&-``): a file opened later would take its number
        try:
            os.fstat(fd)
        except OSError:
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
    # Python leaves a stream that started closed None
    sys.stdout, sys.stderr = (_Sturdy(s or open(os.devnull, "w")) for s in saved)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = saved
