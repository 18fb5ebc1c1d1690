"""Long native work (a fit's or a training's steps) in a worker process that
the command waits for.

A step is one native backward pass of up to minutes, which no signal
interrupts; so the steps run in a spawned worker (no fork after Dr.Jit
started its threads) and Ctrl-C and SIGTERM reach the command, which ends
the worker. The worker's Python is started with the signals a terminal sends
its group ignored (:func:`export.cluster.workers_ignoring_sigint`) and
blocked, and its target ignores them too (:func:`ignore_group_signals`): it
prints nothing of its own, not even while it imports.

The target is called as ``target(connection, *arguments)`` and sends tuples
on the connection: ``("done", ...)`` with the result, ``("error", line)``
for a :class:`core.errors.UsageError`, or any other tag, which is handed to
``on_message`` (a training's step reports).
"""
from __future__ import annotations

import multiprocessing
import signal
from collections.abc import Callable

from core.entry import hold_signals
from core.errors import UsageError
from export.cluster import workers_ignoring_sigint
from renderer.bands import GROUP_SIGNALS


def ignore_group_signals() -> None:
    """A worker's first call: the parent alone answers a terminal's signals
    (a thread of a native library may run with them unblocked)."""
    for signum in GROUP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)


def run_in_worker(target: Callable, arguments: tuple, what: str,
                  on_message: Callable[[tuple], None] | None = None) -> tuple:
    """``target`` in a worker process until it sends ``("done", ...)``: returns
    what follows the tag; an ``("error", line)`` is that UsageError here, and a
    worker that ends without a result is one naming ``what`` ("the fit")."""
    context = multiprocessing.get_context("spawn")
    receiver, sender = context.Pipe(duplex=False)
    worker = context.Process(target=target, args=(sender, *arguments), daemon=True)
    message = None
    try:
        with hold_signals():  # a signal waits until the worker exists, then ends it below
            signal.pthread_sigmask(signal.SIG_BLOCK, GROUP_SIGNALS)  # what a terminal sends the group
            try:
                with workers_ignoring_sigint():
                    worker.start()
            finally:
                signal.pthread_sigmask(signal.SIG_UNBLOCK, GROUP_SIGNALS)
        sender.close()
        while message is None and worker.is_alive() or receiver.poll():
            if not receiver.poll(0.1):
                continue
            try:
                received = receiver.recv()
            except EOFError:
                break
            if received[0] in ("done", "error"):
                message = received
                break
            if on_message is not None:
                on_message(received)
    finally:
        if message is None and worker.is_alive():
            worker.kill()
        if worker.pid is not None:
            worker.join()
    if message is None:
        raise UsageError(f"{what}'s worker process stopped without a result (exit code {worker.exitcode})")
    if message[0] == "error":
        raise UsageError(message[1])
    return message[1:]
