"""What a Dask worker needs before the export's first task reaches it; imported in the workers and,
for a user's cluster, by :func:`export.cluster.dask_client` (it loads Dask)."""
from __future__ import annotations

import ast
import functools
import threading

from distributed import WorkerPlugin

from core.libllvm import prepare_libllvm

#: held by ``ast.parse`` in a worker process (:func:`serialize_ast_parse`)
AST_LOCK = threading.RLock()


def serialize_ast_parse() -> None:
    """Makes ``ast.parse`` in this process one call at a time. CPython 3.11
    keeps the AST constructor's recursion depth per interpreter, not per
    thread: a Dask worker's event loop parses a signature (``inspect``) for
    each task it receives while the task thread's first Mitsuba import parses
    its integrators (``dr.syntax``), and a task failed with "AST constructor
    recursion depth mismatch" (docs/reliability.md). Reentrant: a finalizer
    run inside a parse may parse."""
    parse = ast.parse
    if getattr(parse, "serialized", False):
        return

    @functools.wraps(parse)
    def serialized(*args, **kwargs):
        with AST_LOCK:
            return parse(*args, **kwargs)

    serialized.serialized = True
    ast.parse = serialized


def prepare_worker() -> None:
    """What a worker of a cluster we did not start needs before its first task
    (:func:`export.cluster.dask_setup` does it for our LocalCluster's): its libLLVM chosen, its
    ``ast.parse`` serialized."""
    prepare_libllvm()
    serialize_ast_parse()


class PreparedWorker(WorkerPlugin):
    """:func:`prepare_worker` on every worker of a user's cluster, those that join
    later too (Dask runs ``setup`` on each worker as it registers)."""
    #: one registration per cluster: a second export's replaces the first's
    name = "export-prepared-worker"

    def setup(self, worker) -> None:
        prepare_worker()
