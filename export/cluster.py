"""The export's tasks on a Dask distributed cluster.

Every frame is one task (G-buffers and noisy beauty) plus one task per
ground-truth batch (see :func:`export.store.plan`). They are submitted as
Dask futures and collected with ``as_completed``; this process writes each
result as it arrives (atomically), so only the scene files need to be
readable on the workers, at the same path. Dask reschedules the tasks of a
worker that dies; what was written survives an interrupted client, and the
next run submits only what is missing.

Without a scheduler address a ``LocalCluster`` is started: one worker process
per core (or ``workers``), one task at a time each. Every render runs on one
Dr.Jit thread (:data:`export.sequence.RENDER_THREADS`), so on an existing
cluster start one single-threaded worker per core:
``dask worker ADDRESS --nworkers -1 --nthreads 1`` on each machine.
"""
from __future__ import annotations

import argparse
import atexit
import ipaddress
import logging
import multiprocessing
import multiprocessing.spawn
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing import resource_tracker
from pathlib import Path

from tqdm import tqdm

from core.entry import own_cleanup
from core.errors import ClusterError, UsageError
from core.numbers import ascii_int

from .recorder import Recorder, progress_bar
from .tasks import Task, run_task

#: seconds between looks for a finished task (and for Ctrl-C)
POLL_S = 0.05


def has_dashboard() -> bool:
    """Dask serves its dashboard only where bokeh is installed."""
    try:  # a probe: bokeh is optional
        import bokeh  # noqa: F401, PLC0415  a probe for an optional package, made only when a cluster starts
    except ImportError:
        return False
    return True


def dask_setup(worker) -> None:
    """Dask's preload hook, run in each worker process of our LocalCluster as
    it starts: the process leaves the terminal's process group, so that Ctrl-C
    reaches the export alone, which then stops the cluster (in the group every
    worker would print a traceback, and Mitsuba its warning on stdout). Before
    it, from the worker's first instruction, SIGINT is ignored (:data:`WORKER_PYTHON`).

    The worker logs nothing (:func:`silence_dask`): a task's error reaches the
    export through its future, and what a worker logs otherwise comes from
    losing its scheduler, which happens only as the export ends (its
    heartbeat's traceback after a Ctrl-C)."""
    from .dask_worker import serialize_ast_parse  # noqa: PLC0415  it loads Dask: only in a worker

    os.setpgid(0, 0)
    silence_dask()
    serialize_ast_parse()


#: the workers' interpreter: this process's Python started with SIGINT and SIGHUP ignored (a script)
WORKER_PYTHON = Path(__file__).with_name("worker_python")


@contextmanager
def workers_ignoring_sigint() -> Iterator[None]:
    """Within it, the processes multiprocessing spawns (Dask's workers, a
    training's) start through :data:`WORKER_PYTHON`, the signals a terminal
    sends its group ignored from their first instruction (a blocked signal
    mask is not enough: a native library's thread may run with them
    unblocked while the worker imports); as before where the script cannot run."""
    if not os.access(WORKER_PYTHON, os.X_OK) or not os.access("/bin/sh", os.X_OK):
        yield
        return
    os.environ["EXPORT_WORKER_PYTHON"] = sys.executable
    previous = multiprocessing.spawn.get_executable()
    multiprocessing.set_executable(str(WORKER_PYTHON))
    try:
        yield
    finally:
        multiprocessing.set_executable(previous)


#: ``tcp://HOST:PORT`` or ``HOST:PORT``; an IPv6 host in brackets
SCHEDULER = re.compile(r"(?:tcp://)?(?P<host>\[[^\]/]*\]|[^:/\[\]]+):(?P<port>\d{1,5})")
#: a host name: dot-separated labels of letters, digits and hyphens
HOST_NAME = re.compile(r"(?!-)[A-Za-z0-9-]{1,63}(?<!-)(?:\.(?!-)[A-Za-z0-9-]{1,63}(?<!-))*")


def check_scheduler(address: str) -> str:
    """A Dask scheduler address, ``tcp://HOST:PORT`` or ``HOST:PORT`` with a
    host name or an IP address and a port 1..65535, checked before Dask
    parses it (its own errors are tracebacks); one line naming the flag."""
    usage = "expected tcp://HOST:PORT or HOST:PORT (e.g. tcp://127.0.0.1:8786)"
    match = SCHEDULER.fullmatch(address)
    if match is None:
        raise UsageError(f"--scheduler {address!r}: {usage}")
    host, port = match["host"], int(match["port"])
    if host.startswith("["):
        try:
            ipaddress.IPv6Address(host[1:-1])
        except ValueError:
            raise UsageError(f"--scheduler {address!r}: {host} is not an IPv6 address; {usage}") from None
    elif not HOST_NAME.fullmatch(host) or len(host) > 253:
        raise UsageError(f"--scheduler {address!r}: {host!r} is not a host name or an IP address; {usage}")
    elif re.fullmatch(r"[\d.]+", host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            raise UsageError(f"--scheduler {address!r}: {host} is not an IPv4 address; {usage}") from None
    if not 1 <= port <= 65535:
        raise UsageError(f"--scheduler {address!r}: port {port} is not 1..65535")
    return address


#: the most local worker processes ``--workers`` starts
MAX_WORKERS = 1024


#: where a command's export renders: each option's destination, flag and argparse settings
CLUSTER_OPTIONS = {
    "scheduler": ("--scheduler", dict(metavar="ADDRESS", help="render on a running Dask scheduler (tcp://host:8786)")),
    "workers": ("--workers", dict(type=ascii_int, metavar="N",
                                  help="render on N local Dask worker processes (default: one per core)")),
    "local": ("--local", dict(action="store_true", help="render in this process, without Dask (one core)")),
}


def add_cluster_options(parser: argparse.ArgumentParser) -> None:
    """:data:`CLUSTER_OPTIONS`, one of them at most, for every command that
    renders sequences; :func:`cluster_options` reads them back, checked."""
    where = parser.add_mutually_exclusive_group()
    for name, (flag, settings) in CLUSTER_OPTIONS.items():
        where.add_argument(flag, dest=name, **settings)


def cluster_options(args: argparse.Namespace) -> dict:
    """The options of :func:`add_cluster_options`, checked (one line naming the
    flag), as the keywords of :func:`export.runners.export_sequences`."""
    if args.scheduler is not None:
        check_scheduler(args.scheduler)
    if args.workers is not None and not 1 <= args.workers <= MAX_WORKERS:
        raise UsageError(f"--workers: expected 1..{MAX_WORKERS}, found {args.workers}")
    return {name: getattr(args, name) for name in CLUSTER_OPTIONS}


def silence_dask() -> None:
    """The user gets one line from the command for a failure or an interruption
    (Dask's own reach the export as exceptions, translated there), not what
    Dask logs in the export's process and in the workers of its LocalCluster:
    a lost scheduler's or worker's tracebacks, its INFO lines on closed comms.
    Their child loggers too: Dask gives some a level of their own
    (``tornado.application`` logged a closed stream's traceback)."""
    families = ("distributed", "tornado", "asyncio")
    for name in [*families, *list(logging.root.manager.loggerDict)]:
        if name.split(".")[0] in families:
            logging.getLogger(name).setLevel(logging.CRITICAL)


#: what a worker of the user's own cluster needs (docs/dataset.md)
WORKER_REMEDY = ("every worker needs this project installed (./dev setup) and the scenes at the same path, "
                 "and is started with its .venv/bin/dask worker")


#: seconds a scheduler has to answer; Dask's own timeout, and this much more for the whole connection
CONNECT_S, CONNECT_GRACE_S = 15, 3


def connect(scheduler: str):
    """A Dask client of the scheduler at ``scheduler``; one line (a UsageError)
    where nothing there answers as one. Dask's timeout bounds reaching the
    port, not the handshake: a server of another kind that accepts and stays
    silent held the export forever, and one that answered with other bytes
    ended it in a traceback, so the attempt runs in a thread the export waits
    for a bounded time, and whatever it raises is the line's reason. An
    attempt given up on stays in its thread, where it holds Dask's event loop:
    the command ends after the line; a process that goes on has no other
    Dask client."""
    from distributed import Client  # noqa: PLC0415  Dask loads only for cluster exports

    outcome = {}

    def attempt() -> None:
        try:
            outcome["client"] = Client(scheduler, timeout=f"{CONNECT_S}s")
        except BaseException as error:  # noqa: BLE001  whatever the other end made of the handshake: the reason
            outcome["error"] = error

    thread = threading.Thread(target=attempt, name="dask-connect", daemon=True)
    thread.start()
    thread.join(CONNECT_S + CONNECT_GRACE_S)
    if "client" in outcome:
        return outcome["client"]
    error = outcome.get("error")
    reason = (f"nothing answered as a Dask scheduler within {CONNECT_S + CONNECT_GRACE_S} s" if error is None
              else f"{type(error).__name__}: {error}" if not isinstance(error, (OSError, TimeoutError)) else str(error))
    raise UsageError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({reason})")


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[tuple[object, int | None]]:
    """(a Dask client, the Dr.Jit thread count each worker should use)."""
    from distributed import Client, LocalCluster  # noqa: PLC0415  Dask loads only for cluster exports
    from distributed.deploy.spec import close_clusters  # noqa: PLC0415  as above

    silence_dask()
    cluster = None
    if scheduler:
        client = connect(scheduler)
        # its workers ran no entry point of ours: each chooses its libLLVM before a task (whose
        # module imports Dr.Jit) reaches it, a worker that joins later too (a plugin, not a call);
        # our LocalCluster's workers inherit this process's choice
        from .dask_worker import PreparedWorker  # noqa: PLC0415  it loads Dask, as above

        try:
            client.register_plugin(PreparedWorker())
        except Exception as error:  # noqa: BLE001  whatever a worker's Python made of our code: one line
            client.close()
            raise ClusterError(f"--scheduler {scheduler}: a worker cannot run the export's code "
                               f"({type(error).__name__}: {error})", WORKER_REMEDY) from error
        threads = None
    else:
        cores = os.cpu_count() or 1
        workers = workers or cores
        quiet_resource_tracker()
        try:  # a start cut short by a signal unwinds in Dask's own time: core.entry's watchdog waits for it
            with own_cleanup("starting the Dask cluster"), workers_ignoring_sigint():
                cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=logging.ERROR, preload=[__name__])
        except BaseException:
            # interrupted while its workers start: Dask's exit hook would close a cluster whose
            # workers never finished starting (an AssertionError traceback); they end with this
            # process (multiprocessing terminates them, and each watches its parent)
            atexit.unregister(close_clusters)
            raise
        client = Client(cluster)
        threads = max(1, cores // workers)
    try:
        yield client, threads
    finally:
        with own_cleanup("closing the Dask cluster"):  # core.entry's watchdog waits for it
            client.close()
            if cluster is not None:
                cluster.close()


def quiet_resource_tracker() -> None:
    """Starts :mod:`multiprocessing`'s resource tracker (where it is not running yet)
    with its stderr on the null device. A run that a signal ends leaves the exit
    to :func:`core.entry.end_now`, which terminates the workers and skips the
    teardown; the tracker then removes the semaphores of the cluster's workers,
    as it should, but would also warn of them on the terminal after the run's one
    line, once the shell's prompt is back."""
    saved = os.dup(2)
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        resource_tracker.ensure_running()
    finally:
        os.dup2(saved, 2)
        os.close(saved)


@contextmanager
def deferred_signals() -> Iterator[Callable[[], None]]:
    """Within it, SIGINT and SIGTERM are only noted; the function it yields
    raises a noted one (through its previous handler: KeyboardInterrupt for
    Ctrl-C) where it is called. Raised wherever the main thread happened to
    be, the exception could land in code that swallows it (one of Dask's
    finalizers; native code rendering a task in this process), and the export
    would go on to the end and exit 0."""
    noted: list[int] = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            handler = signal.getsignal(signum)
            if handler is not signal.SIG_IGN:
                previous[signum] = signal.signal(signum, lambda number, frame: noted.append(number))

    def restore() -> None:
        for number, handler in previous.items():
            signal.signal(number, handler)
        previous.clear()

    def raise_noted() -> None:
        if not noted:
            return
        handler = previous.get(noted[0], signal.SIG_DFL)
        restore()
        if callable(handler):
            handler(noted[0], None)  # the command's handlers raise
        else:
            os.kill(os.getpid(), noted[0])  # the default action: ends the process

    try:
        yield raise_noted
    finally:
        restore()


class WorkerWatch:
    """Says once on stderr when the export waits on a cluster without workers (a
    scheduler of the user's with none yet, or whose workers all died), and
    once when workers are back; looks every :data:`WORKER_LOOK_S` without a result."""

    def __init__(self, client):
        self.client, self.since, self.said = client, time.monotonic(), False

    def reset(self) -> None:
        self.since = time.monotonic()

    def look(self) -> None:
        if time.monotonic() - self.since < WORKER_LOOK_S:
            return
        self.since = time.monotonic()
        try:
            workers = len(self.client.nthreads())
        except Exception:  # noqa: BLE001  a scheduler gone: its cancelled tasks say so, in one line
            return
        if workers == 0 and not self.said:
            address = self.client.scheduler.address
            tqdm.write(f"export: waiting: the Dask scheduler at {address} has no workers; start one "
                       f"(.venv/bin/dask worker {address}) or press Ctrl-C", file=sys.stderr)
        elif workers and self.said:
            tqdm.write(f"export: {workers} worker{'s' * (workers > 1)} joined; going on", file=sys.stderr)
        self.said = workers == 0


#: seconds without a result after which the export looks whether its cluster has workers
WORKER_LOOK_S = 5.0


def run_futures(client, tasks: list[Task], recorder: Recorder, after_task: Callable[[Task], None] | None = None,
                total_frames: int = 0) -> None:
    """Submits ``tasks`` (earlier frames first) and records results as they complete."""
    from distributed import as_completed  # noqa: PLC0415  Dask loads only for cluster exports

    futures = {}
    for order, task in enumerate(tasks):
        future = client.submit(run_task, task, key=task.name, priority=len(tasks) - order)
        futures[future] = task
    try:
        waiting = WorkerWatch(client)
        with deferred_signals() as raise_noted, progress_bar(len(tasks), total_frames) as bar:
            completed = as_completed(futures, with_results=True)
            while not completed.is_empty():
                raise_noted()
                if not completed.has_ready():
                    waiting.look()
                    time.sleep(POLL_S)
                    continue
                waiting.reset()
                future, outcome = next_outcome(completed, len(futures), len(tasks))
                result, timing = outcome
                task = futures.pop(future)
                recorder.record(task, result, timing)
                bar.update()
                bar.set_postfix(frames=f"{recorder.frames_done()}/{total_frames}", refresh=False)
                if after_task:
                    after_task(task)
            raise_noted()
    finally:
        if futures:  # interrupted: the cluster stops working for us
            client.cancel(list(futures))


#: what the user is told after a cluster failure: what stays and what to do
CLUSTER_REMEDY = "the finished frames are complete; the same command again resumes with the others"


def next_outcome(completed, unfinished: int, total: int) -> tuple[object, tuple]:
    """The next (future, its result) of ``completed``; a task's own error is raised as
    it is, the cluster's failures as one :class:`ClusterError` with the remedy."""
    from distributed import CancelledError, KilledWorker  # noqa: PLC0415  Dask loads only for cluster exports

    try:
        future, outcome = next(completed)
    except KilledWorker as error:
        raise ClusterError(f"the Dask cluster lost a worker on task {error.task} {error.allowed_failures + 1} "
                           f"times, more than it retries ({unfinished} of {total} tasks unfinished)",
                           CLUSTER_REMEDY) from error
    if isinstance(outcome, CancelledError):  # not by us: we cancel only once we stop reading them
        reason = getattr(outcome, "reason", "unknown")
        raise ClusterError(f"the Dask scheduler cancelled the export's tasks ({unfinished} of {total} unfinished; "
                           f"Dask's reason: {reason})", CLUSTER_REMEDY) from outcome
    return future, outcome


def cluster_description(client, scheduler: str | None = None) -> dict:
    """What the manifest records about the cluster (and the dashboard's link, on stderr)."""
    info = client.scheduler_info()
    if has_dashboard():
        print(f"export: Dask dashboard at {client.dashboard_link}", file=sys.stderr)
    return {"runner": "dask", "scheduler": scheduler or info.get("address"),
            "workers": len(info.get("workers", {}))}
