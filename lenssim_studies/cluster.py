"""Sweeps on a dask.distributed cluster: every chunk of a sweep is one dask task.

The cluster is any running dask scheduler (``scheduler="tcp://host:8786"``: started by hand, over SSH, by
SLURM/PBS through dask-jobqueue, on Kubernetes; see docs/scale-out.md) or a ``LocalCluster`` of ``workers``
processes on this machine. The client (the process that runs :func:`lenssim.sweep.run_sweep`) submits one
task per missing chunk and writes each finished chunk as it arrives, into the same checked chunk files
as a run in one process; the final file is assembled from those files in the same way. So:

* the output is byte-identical to the single-process run, provided the workers compute with the same
  number of torch threads (the last bits of torch's parallel reductions depend on it): each task sets
  the client's count (``threads``, default ``torch.get_num_threads()`` here);
* an interrupted client loses only the chunks in flight; the same command continues from the files;
* a worker that dies mid-task is survived: the scheduler gives its task to another worker (dask's
  ``distributed.scheduler.allowed-failures``); a task that raises is retried :data:`TASK_RETRIES` times;
* every chunk travels with the SHA-256 of its arrays, checked by the client before it is written.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import torch

__all__ = ["TASK_RETRIES", "ClusterError", "dask_client", "compute_chunks"]

TASK_RETRIES = 2
"""Times a chunk task that raised is tried again (a lost worker's task is re-run by the scheduler anyway)."""

CONNECT_TIMEOUT_S = 30
"""Seconds to wait for a scheduler at a given address."""


class ClusterError(Exception):
    """The cluster cannot run the sweep as the client asks (a worker without lenssim, or another version)."""


WORKER_MALLOC = {"M_TRIM_THRESHOLD": (-1, 2**30), "M_MMAP_THRESHOLD": (-3, 32 * 2**20)}
"""glibc ``mallopt`` settings for a worker process: ``{name: (parameter number, bytes)}``.

dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``. Setting that fixes glibc's mmap
threshold at its 128 kB default, so each of the sweep's large temporaries is a fresh ``mmap`` whose pages
the kernel faults in and zeroes: a chunk took 5x as long in a worker as in one process (half of it in
the kernel). Large temporaries come from the reused heap instead with these values (the dynamic
threshold's own ceiling, 32 MB, and a 1 GB trim threshold)."""

_MALLOC_SET = False


def _numeric_malloc() -> None:
    """Apply :data:`WORKER_MALLOC` once per process (glibc only; elsewhere nothing to do)."""
    global _MALLOC_SET
    if _MALLOC_SET:
        return
    _MALLOC_SET = True
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
    except OSError:
        return
    for param, value in WORKER_MALLOC.values():
        libc.mallopt(ctypes.c_int(param), ctypes.c_int(value))


def with_threads(threads: int, fn):
    """``fn()`` with ``threads`` torch threads (a task's count: the last bits of torch's reductions depend on it),
    the worker's own count restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        return fn()
    finally:
        torch.set_num_threads(before)


def _chunk_task(config: dict, digest: str, index: int, device: str, threads: int) -> tuple[int, dict, str]:
    """On a worker: chunk ``index`` of the sweep ``config`` -> ``(index, arrays, sha256 of the arrays)``."""
    from .chunks import _checksum, _compute_chunk
    from .config import SweepConfig
    from lenssim.torch_utils import select_device

    _numeric_malloc()

    cfg = SweepConfig.from_dict(config)
    if cfg.digest() != digest:
        raise ClusterError(f"the worker's lenssim reads this sweep config differently (digest {cfg.digest()} != "
                           f"{digest}): install the client's lenssim version on every worker")
    chunk = with_threads(threads, lambda: _compute_chunk(cfg, index, select_device(device), None))
    return index, chunk, _checksum(chunk)


def check_scheduler(address: str) -> None:
    """Refuse, before any work, a ``--scheduler`` address that is malformed or where no dask scheduler answers
    (connects once, within the client's timeout, and closes)."""
    from distributed.comm import parse_address

    if not isinstance(address, str) or not address.strip():
        raise ValueError(f"--scheduler {address!r} is not allowed: a dask scheduler address such as tcp://HOST:8786")
    try:
        parse_address(address, strict=True)
        host_port = address.split("://", 1)[1]
        if host_port.rpartition(":")[2].isdigit() is False:
            raise ValueError("no port")
    except ValueError:
        raise ValueError(f"--scheduler {address!r} is not allowed: a dask scheduler address such as "
                         "tcp://HOST:8786 (protocol, host and port)") from None
    with dask_client(address):
        pass


@contextmanager
def _environment_kept():
    """This process's environment as it was on entry, put back by the function yielded and on exit.

    dask's nanny sets its workers' variables (``distributed.nanny.pre-spawn-environ``: ``OMP_NUM_THREADS=1``,
    ``MKL_NUM_THREADS=1``, ``OPENBLAS_NUM_THREADS=1``, ``PYTHONHASHSEED``, ...) in the spawning process's own
    ``os.environ`` before it starts each worker, and leaves them there: every later subprocess of the caller then ran
    on one thread (measured: the any-lens gallery example, a subprocess of the test suite after a local cluster,
    14 -> 37 s). The nanny sets them again before each spawn (a restarted worker keeps its settings)."""
    saved = dict(os.environ)

    def restore() -> None:
        for key in [k for k in os.environ if k not in saved]:
            del os.environ[key]
        for key, value in saved.items():
            if os.environ.get(key) != value:
                os.environ[key] = value

    try:
        yield restore
    finally:
        restore()


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None):
    """A ``distributed.Client``: of the scheduler at ``scheduler``, or of a new ``LocalCluster`` of ``workers``
    processes (one task at a time each), closed on exit."""
    from distributed import Client, LocalCluster

    if (scheduler is None) == (workers is None):
        raise ValueError("give either a scheduler address or a number of local workers")
    if scheduler is not None:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except OSError as exc:
            raise ConnectionError(f"no dask scheduler answers at {scheduler!r} within {CONNECT_TIMEOUT_S} s "
                                  f"({type(exc).__name__})") from None
        with client:
            yield client
        return
    from lenssim.validate import check_int

    workers = check_int("workers", workers, 1)
    import dask

    # no MALLOC_TRIM_THRESHOLD_ in the workers' environment (see WORKER_MALLOC); this process's own environment is
    # left as it was (the nanny writes the workers' variables into it)
    with _environment_kept() as restore, \
            dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}), \
            LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                         silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        restore()
        yield client


def compute_chunks(client, cfg, indices, *, device: str = "auto", threads: int | None = None, task=None,
                   kind: str = "sweep") -> Iterator[tuple[int, dict]]:
    """Chunks ``indices`` of the sweep ``cfg`` as dask tasks on ``client``'s cluster; yields ``(index, arrays)``
    in the order they finish, each checked against the checksum computed where it was made. ``task(config, digest,
    index, device, threads) -> (index, arrays, sha256)`` (default: a sweep's chunk, with ``cfg.to_dict()`` as the
    config; another run passes its own task and ``cfg`` itself, e.g. the tolerance Monte Carlo); ``kind`` names the
    tasks."""
    from distributed import as_completed

    from .chunks import _checksum

    threads = int(threads or torch.get_num_threads())
    config, digest = (cfg.to_dict() if task is None else cfg), cfg.digest()
    task = _chunk_task if task is None else task
    futures = [client.submit(task, config, digest, i, device, threads, key=f"lenssim-{kind}-{digest}-{i:05d}",
                             pure=False, retries=TASK_RETRIES) for i in indices]
    try:
        for fut in as_completed(futures):
            try:
                i, chunk, sha = fut.result()
            except ImportError as exc:  # the task could not even be unpickled on the worker
                raise ClusterError(f"a dask worker cannot import what the sweep needs ({exc}); install the client's "
                                   "lenssim (and torch) on every worker") from None
            chunk = {k: np.asarray(v) for k, v in chunk.items()}
            if _checksum(chunk) != sha:
                raise ValueError(f"sweep chunk {i} arrived from its worker corrupted (checksum mismatch)")
            fut.release()
            yield i, chunk
    finally:
        for fut in futures:
            fut.cancel()
