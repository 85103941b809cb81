"""Where `bench` and `tune` run their logs: a local process pool, or a Dask cluster.

One interface for both, so the callers have one code path:

    with Fleet(workers=2) as fleet:                 # local processes (fork), or in-process for 1
        for result in fleet.map_unordered(fn, items): ...
    with Fleet(scheduler="tcp://host:8786") as fleet:   # Dask distributed, past one machine
        results = fleet.map(fn, items)               # in the order of items

`fn` must be a module-level function (it is pickled to the workers) and its items plain data;
each worker keeps its own caches (logs read, filters compiled) between calls, so a pool lives
as long as the Fleet. On a cluster the workers must see the same files (logs, the repository)
at the same paths, and have this package installed.
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Callable, Iterable, Iterator

from ahrsgen.errors import ConfigError


class Fleet:
    def __init__(self, workers: int = 2, scheduler: str | None = None, timeout: str = "20s"):
        self.workers = max(1, int(workers))
        self.scheduler = scheduler
        self._pool = None
        self._client = None
        if scheduler:
            try:
                from distributed import Client
            except ImportError:
                raise ConfigError("--scheduler needs Dask distributed: pip install 'ahrsgen[fleet]'") from None
            try:
                self._client = Client(scheduler, timeout=timeout)
            except (OSError, TimeoutError, ValueError) as e:
                raise ConfigError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None

    @property
    def where(self) -> str:
        if self._client is not None:
            n = len(self._client.scheduler_info().get("workers", {}))
            return f"Dask scheduler {self.scheduler} ({n} worker(s))"
        return f"{self.workers} local process(es)" if self.workers > 1 else "this process"

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        self.close(interrupted=exc_type is not None and issubclass(exc_type, KeyboardInterrupt))

    def close(self, interrupted: bool = False) -> None:
        if self._pool is not None:
            if interrupted:          # Ctrl-C: the workers ignore it (_ignore_sigint); end them now
                for proc in list(getattr(self._pool, "_processes", {}).values()):
                    proc.terminate()
                self._pool.shutdown(wait=False, cancel_futures=True)
            else:
                self._pool.shutdown(cancel_futures=True)
            self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None

    def map_unordered(self, fn: Callable, items: Iterable) -> Iterator:
        """Results as they complete."""
        items = list(items)
        if self._client is not None:
            from distributed import as_completed as dask_completed
            futures = self._client.map(fn, items, pure=False)
            for fut in dask_completed(futures):
                yield fut.result()
            return
        if self.workers == 1 or len(items) <= 1:
            for it in items:
                yield fn(it)
            return
        if self._pool is None:
            import multiprocessing as mp
            self._pool = ProcessPoolExecutor(self.workers, mp_context=mp.get_context("fork"),
                                             initializer=_ignore_sigint)
        futures = [self._pool.submit(fn, it) for it in items]
        for fut in as_completed(futures):
            yield fut.result()

    def map(self, fn: Callable, items: Iterable) -> list:
        """Results in the order of items."""
        items = list(items)
        tagged = self.map_unordered(_Tagged(fn), list(enumerate(items)))
        out = [None] * len(items)
        for i, r in tagged:
            out[i] = r
        return out


class _Tagged:
    """fn wrapped to return (index, result), picklable."""

    def __init__(self, fn):
        self.fn = fn

    def __call__(self, item):
        i, x = item
        return i, self.fn(x)


def _ignore_sigint() -> None:
    """In a worker: Ctrl-C reaches the whole process group, and only the parent answers it (one
    line, exit 130, the workers ended by Fleet.close), not every worker with a traceback."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
