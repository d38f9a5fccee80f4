"""Where the planner's tasks run: in this process, on a new LocalCluster, or on a Dask cluster.

One runner serves every command that spreads work over tasks: ``sweep``
(:func:`planner.sweep.sweep_setups`), ``rank --scheduler``
(:func:`planner.sweep.screen_setups_on`) and ``whatif --scheduler``
(:func:`planner.whatif.evaluate_whatif`). :func:`start_runner` turns a `scheduler` (or a
`client`) into a runner:

- ``"none"`` (or ``"single"``, ``"serial"``): a :class:`SerialRunner`, every task in this
  process, in order;
- ``"local"`` (the default): a :class:`DaskRunner` on a new
  :class:`dask.distributed.LocalCluster`, one worker a core, each with one thread (and one
  compiled-kernel thread: the workers are the parallelism);
- an address (``"tcp://host:8786"``): a :class:`DaskRunner` joined to a running scheduler,
  which must have a worker within :data:`CONNECT_TIMEOUT_S`;
- a given ``distributed.Client``: a :class:`DaskRunner` on it (left open at the end).

A runner has ``kind`` (``"none"``, ``"local"``, ``"address"`` or ``"client"``), ``address``,
``n_workers``, ``n_threads`` and four methods: ``scatter(obj)`` (a reference the tasks
take, the object itself when serial), ``everywhere(func, *args)`` (run on every worker),
``map_unordered(func, argslist, progress, desc)`` (yields ``(j, result)`` as tasks finish,
a bounded number in flight) and ``close()``.

The compiled parallel kernels must not be launched by two threads at once: every task holds
:data:`KERNEL_LOCK` around its kernel calls. ``distributed`` is imported only when a cluster
is used (it is heavy; ``shockplan --help`` never loads it).
"""

from __future__ import annotations

import logging
import os
import threading

from planner.errors import PlannerError

__all__ = [
    "SCHEDULER_NONE",
    "SCHEDULER_LOCAL",
    "CONNECT_TIMEOUT_S",
    "KERNEL_LOCK",
    "SerialRunner",
    "DaskRunner",
    "start_runner",
]

#: Values of `scheduler` that run everything in this process.
SCHEDULER_NONE = ("none", "single", "serial")
#: Values of `scheduler` that start a LocalCluster on this machine.
SCHEDULER_LOCAL = ("local",)
#: Seconds to wait for a scheduler given by address.
CONNECT_TIMEOUT_S = 10.0

#: Compiled parallel kernels must not be launched by two threads at once (numba's workqueue
#: layer is not thread-safe): held around every kernel call of a task, uncontended in
#: process workers with one thread each.
KERNEL_LOCK = threading.Lock()


class SerialRunner:
    """Runs tasks in this process, in order."""

    kind = "none"
    address = None
    n_workers = 1
    n_threads = 1

    def scatter(self, obj):
        """Return `obj` as is (tasks run in this process)."""
        return obj

    def everywhere(self, func, *args):
        """Call ``func(*args)`` once, in this process."""
        func(*args)

    def map_unordered(self, func, argslist, progress, desc):
        """Yield ``(j, func(*argslist[j]))`` in order, with a progress bar when asked."""
        from tqdm.auto import tqdm

        for j, args in enumerate(tqdm(argslist, desc=desc, unit="task", disable=not progress)):
            yield j, func(*args)

    def close(self):
        """Nothing to release."""
        pass


class DaskRunner:
    """Runs tasks on a dask.distributed client, a bounded number in flight."""

    def __init__(self, client, kind, cluster=None, *, own_client=False):
        self.client = client
        self.kind = kind
        self.cluster = cluster
        self.own_client = own_client or cluster is not None
        self.address = client.scheduler.address
        info = client.scheduler_info()
        self.n_workers = max(1, len(info.get("workers", {})))
        self.n_threads = max(1, sum(w.get("nthreads", 1)
                                    for w in info.get("workers", {}).values()))

    def scatter(self, obj):
        """Send `obj` to every worker once; tasks take the returned future."""
        return self.client.scatter(obj, broadcast=True, hash=False)

    def everywhere(self, func, *args):
        """Call ``func(*args)`` on every worker."""
        self.client.run(func, *args)

    def map_unordered(self, func, argslist, progress, desc):
        """Yield ``(j, result)`` as tasks finish, a bounded number in flight."""
        # distributed is heavy and optional: imported only when a cluster runs
        from distributed import as_completed
        from tqdm.auto import tqdm

        window = 2 * self.n_threads + 1  # bounded memory: results wait at most this many
        pending = iter(enumerate(argslist))
        futures = as_completed(loop=self.client.loop)
        tag = {}
        for j, args in pending:
            fut = self.client.submit(func, *args, pure=False)
            tag[fut.key] = j
            futures.add(fut)
            if futures.count() >= window:
                break
        with tqdm(total=len(argslist), desc=desc, unit="task", disable=not progress) as bar:
            for fut in futures:
                j = tag.pop(fut.key)
                result = fut.result()
                fut.release()
                bar.update(1)
                nxt = next(pending, None)
                if nxt is not None:
                    new = self.client.submit(func, *nxt[1], pure=False)
                    tag[new.key] = nxt[0]
                    futures.add(new)
                yield j, result

    def close(self):
        """Close the client and the cluster this runner started."""
        if self.own_client:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def start_runner(scheduler, client, n_workers, processes, where="sweep"):
    """The task runner for `scheduler`/`client`: serial, a new LocalCluster, or a client.

    Parameters
    ----------
    scheduler : str or None
        ``"local"`` (also ``None``), ``"none"`` or a scheduler address.
    client : distributed.Client or None
        A client to run on instead (then `scheduler` must be None).
    n_workers : int or None
        Workers of a new LocalCluster (default: one a core).
    processes : bool
        Process workers (True) or thread workers of a new LocalCluster.
    where : str
        The command named in the errors (``sweep``, ``rank``, ``whatif``).

    Returns
    -------
    SerialRunner or DaskRunner
    """
    if client is not None:
        if scheduler is not None:
            raise PlannerError(f"{where}: give a scheduler or a client, not both")
        return DaskRunner(client, "client")
    if scheduler is not None and not isinstance(scheduler, str):
        raise TypeError(f"{where}: scheduler must be 'local', 'none' or a scheduler address "
                        f"(str), got {type(scheduler).__name__}")
    name = "local" if scheduler is None else scheduler.strip()
    if name.lower() in SCHEDULER_NONE:
        return SerialRunner()
    # distributed is heavy and optional: imported only when a cluster runs
    from distributed import Client, LocalCluster

    if name.lower() in SCHEDULER_LOCAL:
        n = (os.cpu_count() or 1) if n_workers is None else int(n_workers)
        if n < 1:
            raise PlannerError(f"{where}: n_workers={n_workers!r} must be at least 1")
        # one compiled-kernel thread per worker: the workers are the parallelism
        kwargs = {"env": {"NUMBA_NUM_THREADS": "1"}} if processes else {}
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=processes,
                               dashboard_address=None, silence_logs=logging.ERROR, **kwargs)
        return DaskRunner(Client(cluster, set_as_default=False), "local", cluster)
    if "://" not in name and ":" not in name:
        raise PlannerError(f"{where}: scheduler {scheduler!r} is neither 'local', 'none' nor a "
                           "scheduler address; give an address such as tcp://10.0.0.5:8786 "
                           "(from `dask scheduler`), 'local' for a cluster on this machine, "
                           "or 'none' for one process")
    try:
        client = Client(name, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        text = " ".join(str(exc).split()) or type(exc).__name__
        raise PlannerError(f"{where}: cannot reach the Dask scheduler at {name!r} within "
                           f"{CONNECT_TIMEOUT_S:g} s ({text}); check the address and that "
                           "`dask scheduler` runs there, or use scheduler='local' (this "
                           "machine) or 'none' (one process)") from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        client.close()
        raise PlannerError(f"{where}: the Dask scheduler at {name!r} has no workers after "
                           f"{CONNECT_TIMEOUT_S:g} s; start some with `dask worker {name}` "
                           "(in this project's environment)") from exc
    return DaskRunner(client, "address", own_client=True)
