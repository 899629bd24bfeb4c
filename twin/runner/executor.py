"""One executor interface for campaigns: in-process, local processes, or a Dask cluster.

All three are ``concurrent.futures.Executor`` objects: :class:`SerialExecutor` (runs each call at submit;
for one worker and for tests), a ``ProcessPoolExecutor`` (default; ``spawn`` start method, because a
forked child must not inherit an OpenGL context of the parent), or a Dask ``distributed.Client``'s
``get_executor()`` (``--dask ADDRESS``). :func:`run_tasks` submits work, hands every finished result to a
callback in the calling process (which writes it to disk at once), and cancels the rest on the first error.

:func:`worker_identity` tells where a task ran (host, process id, Dask worker address), so tests and logs
can prove that work ran on a cluster's workers and not in the local process.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import socket
import sys
from typing import Any, Callable, Iterator, Sequence

__all__ = [
    "SerialExecutor",
    "open_executor",
    "run_tasks",
    "worker_identity",
]


class SerialExecutor(cf.Executor):
    """Runs every submitted call immediately in the calling process (a one-worker executor)."""

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[override]
        f: cf.Future = cf.Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            if isinstance(exc, (KeyboardInterrupt, SystemExit)):
                raise
            f.set_exception(exc)
        return f


@contextlib.contextmanager
def open_executor(kind: str = "process", workers: int = 2, address: str | None = None) -> Iterator[cf.Executor]:
    """An executor of ``kind`` ``'serial'``, ``'process'`` or ``'dask'`` (``address`` of a Dask scheduler,
    e.g. ``tcp://10.0.0.5:8786``, or a ``distributed.Client`` / ``LocalCluster`` object)."""
    if kind == "serial":
        yield SerialExecutor()
    elif kind == "process":
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as ex:
            yield ex
    elif kind == "dask":
        if address is None:
            raise ValueError("address is required for kind='dask' (a scheduler address such as tcp://host:8786)")
        try:
            from distributed import Client
        except ImportError:  # pragma: no cover - depends on the installation
            raise ValueError("kind='dask' needs dask.distributed: pip install 'twin[dask]'") from None
        if isinstance(address, Client):
            yield address.get_executor(pure=False)
        else:
            client = Client(address)
            try:
                yield client.get_executor(pure=False)
            finally:
                client.close()
    else:
        raise ValueError(f"kind must be 'serial', 'process' or 'dask', got {kind!r}")


def run_tasks(
    executor: cf.Executor,
    fn: Callable[..., Any],
    items: Sequence[Any],
    *,
    args: tuple = (),
    on_done: Callable[[Any, Any], None] | None = None,
) -> list[Any]:
    """Run ``fn(*args, item)`` for every item; return results in item order.

    ``on_done(item, result)`` runs in the calling process as each result arrives (in completion order), so a
    campaign writes every finished pose at once. The first exception cancels what has not started and is
    re-raised; results already handed to ``on_done`` are kept by the caller.
    """
    out: list[Any] = [None] * len(items)
    if isinstance(executor, SerialExecutor):
        # In-process: hand each result over before the next call, so an interruption loses nothing finished.
        for k, item in enumerate(items):
            out[k] = fn(*args, item)
            if on_done is not None:
                on_done(item, out[k])
        return out
    futures = {executor.submit(fn, *args, item): k for k, item in enumerate(items)}
    try:
        for fut in cf.as_completed(futures):
            k = futures[fut]
            res = fut.result()
            out[k] = res
            if on_done is not None:
                on_done(items[k], res)
    except BaseException:
        for fut in futures:
            fut.cancel()
        raise
    return out


def worker_identity() -> dict[str, Any]:
    """Where the calling code runs: host, process id and, inside a Dask worker, its address."""
    ident: dict[str, Any] = {"host": socket.gethostname(), "pid": os.getpid(), "dask_worker": None}
    # A Dask worker runs in a process that has imported distributed: where it is not imported, no worker runs
    # the caller (and importing it to ask would cost a process ~0.5 s of CPU).
    distributed = sys.modules.get("distributed")
    if distributed is not None:
        try:
            ident["dask_worker"] = distributed.get_worker().address
        except ValueError:
            pass
    return ident
