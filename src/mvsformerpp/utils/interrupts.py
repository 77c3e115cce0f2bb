"""Steps that Ctrl-C must not cut in two: the interrupt waits for the step's end, then stops the run."""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator


@contextlib.contextmanager
def deferred_interrupt() -> Iterator[None]:
    """Hold SIGINT (Ctrl-C) back while the block runs; when one came, raise :class:`KeyboardInterrupt` after it.

    For steps made of several writes and renames that only together leave a valid state (a checkpoint pair,
    a workspace swapped into place): the step finishes, and the run stops as any interrupted run does. In a
    thread other than the main one (where no signal handler can be set) the block runs unguarded.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if received:
        if callable(previous):
            previous(signal.SIGINT, None)  # the default handler raises KeyboardInterrupt
        elif previous == signal.SIG_DFL:
            raise KeyboardInterrupt
