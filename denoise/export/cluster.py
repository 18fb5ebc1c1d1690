"""The export's tasks on a Dask distributed cluster.

Every frame is one task (G-buffers and noisy beauty) plus one task per
ground-truth batch (see :func:`denoise.export.store.plan`). They are submitted as
Dask futures and collected with ``as_completed``; this process writes each
result as it arrives (atomically), so only the scene files need to be
readable on the workers, at the same path. Dask reschedules the tasks of a
worker that dies; what was written survives an interrupted client, and the
next run submits only what is missing.

Without a scheduler address a ``LocalCluster`` is started: one worker process
per core (or ``workers``), one task at a time each. Every render runs on one
Dr.Jit thread (:data:`denoise.export.sequence.RENDER_THREADS`), so on an existing
cluster start one single-threaded worker per core:
``dask worker ADDRESS --nworkers -1 --nthreads 1`` on each machine.
"""
from __future__ import annotations

import logging
import os
import sys
from contextlib import contextmanager
from typing import Callable, Iterator

from core.errors import UsageError

from .recorder import Recorder, progress_bar
from .tasks import Task, run_task


def has_dashboard() -> bool:
    """Dask serves its dashboard only where bokeh is installed."""
    try:  # a probe: bokeh is optional
        import bokeh  # noqa: F401
    except ImportError:
        return False
    return True


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[tuple[object, int | None]]:
    """(a Dask client, the Dr.Jit thread count each worker should use)."""
    from distributed import Client, LocalCluster  # Dask loads only for cluster exports

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout="15s")
        except (OSError, TimeoutError) as error:
            raise UsageError(f"--scheduler {scheduler}: cannot reach a Dask scheduler there ({error})") from None
        threads = None
    else:
        cores = os.cpu_count() or 1
        workers = workers or cores
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=":0", silence_logs=logging.ERROR)
        client = Client(cluster)
        threads = max(1, cores // workers)
    try:
        yield client, threads
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_futures(client, tasks: list[Task], recorder: Recorder, after_task: Callable[[Task], None] | None = None,
                total_frames: int = 0) -> None:
    """Submits ``tasks`` (earlier frames first) and records results as they complete."""
    from distributed import as_completed  # Dask loads only for cluster exports

    futures = {}
    for order, task in enumerate(tasks):
        future = client.submit(run_task, task, key=task.name, priority=len(tasks) - order)
        futures[future] = task
    try:
        with progress_bar(len(tasks), total_frames) as bar:
            for future, (result, timing) in as_completed(futures, with_results=True):
                task = futures.pop(future)
                recorder.record(task, result, timing)
                bar.update()
                bar.set_postfix(frames=f"{recorder.frames_done()}/{total_frames}", refresh=False)
                if after_task:
                    after_task(task)
    finally:
        if futures:  # interrupted: the cluster stops working for us
            client.cancel(list(futures))


def cluster_description(client, scheduler: str | None = None) -> dict:
    """What the manifest records about the cluster (and the dashboard's link, on stderr)."""
    info = client.scheduler_info()
    if has_dashboard():
        print(f"denoise.export: Dask dashboard at {client.dashboard_link}", file=sys.stderr)
    return {"runner": "dask", "scheduler": scheduler or info.get("address"),
            "workers": len(info.get("workers", {}))}
