"""Where parallel work runs: this machine's processes or a Ray cluster. The one place that picks
between them (`--backend local|ray`), for rendering and fusion alike.

    backend = make_backend("local", workers=4)           # or make_backend("ray", address=...)
    for result in backend.map(fuse_one, frame_dirs, shared=cfg): ...   # fn(job, shared) per job
    backend.slots(cpus=threads)                           # how many long-lived workers fit
    worker = backend.start(WorkerProcess, cpus=threads)   # one of them: .run(job) yields, .close()

`map` runs stateless jobs: locally in `workers` spawned processes (in this process when
workers <= 1), results in job order; on Ray as tasks in batches, results as batches finish (a
batch lost with its node is run again: jobs must be idempotent; `workers` caps the batches running
at once). `start` makes one stateful worker: locally the object itself, on Ray an actor owning
it whose `run` streams back what it yields; an actor that dies raises WorkerLost, an exception
the worker raises arrives as itself. Ray is imported only by the Ray backend.

Lifetimes: local pool processes die with the command (common.lifetime). On Ray, when no node with
a CPU has been alive for RAY_NODE_TIMEOUT_S seconds (env FISHEYE_BEV_RAY_NODE_TIMEOUT_S, default
60) while work waits, `map` and a worker's `run` raise ClusterGone (one line, exit 1); what was
finished is on disk, so the same command run again resumes.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from .errors import InputError, MachineError
from .lifetime import DieWithParent
from .resources import CODE_DIR

BACKENDS = ("local", "ray")


RAY_NODE_TIMEOUT_S = 60.0  # default wait for a live Ray node with a CPU (docs/scaling.md)
POLL_S = 1.0


class WorkerLost(Exception):
    """A worker (process, Ray actor or node) went away mid-job: its unfinished work can be redone."""


class ClusterGone(MachineError):
    """No Ray node with a CPU has been alive for the node timeout: the run stops, resumable."""


def add_backend_args(ap) -> None:
    ap.add_argument("--backend", choices=BACKENDS, default="local",
                    help="local: a process pool on this machine (default); ray: a Ray cluster")
    ap.add_argument("--address", default=None,
                    help="Ray cluster address (default: 'auto' when RAY_ADDRESS is set, else a Ray instance on this machine)")


def make_backend(name: str = "local", workers: int | None = None, address: str | None = None):
    """`workers`: at most this many parallel workers (local default: one per core)."""
    if workers is not None and workers < 1:
        raise InputError(f"--workers: must be >= 1, got {workers}")
    if name == "local":
        return LocalBackend(workers)
    if name == "ray":
        return RayBackend(address, workers)
    raise InputError(f"--backend: must be one of {', '.join(BACKENDS)}, got {name!r}")


# ------------------------------------------------------------------ local processes

_FN = None
_SHARED = None


def _init_process(fn, shared, parent) -> None:
    global _FN, _SHARED
    parent()  # a pool process dies with the command that started it (common.lifetime)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    _FN, _SHARED = fn, shared


def _call(job):
    return _FN(job, _SHARED)


class LocalBackend:
    name = "local"
    retries_lost_workers = False  # a worker lost here is a crash of this machine's Blender: the run stops

    def __init__(self, workers: int | None = None):
        self.workers = workers

    def slots(self, cpus: int = 1) -> int:
        """Parallel workers: `workers`, else one per core."""
        return self.workers or os.cpu_count() or 1

    def map(self, fn, jobs: list, shared=None):
        """Yield fn(job, shared) for every job, in order (`fn`: a module-level function)."""
        if (self.workers or 1) <= 1:
            yield from (fn(j, shared) for j in jobs)
            return
        from concurrent.futures import ProcessPoolExecutor
        from multiprocessing import get_context

        pool = ProcessPoolExecutor(self.workers, mp_context=get_context("spawn"), initializer=_init_process,
                                   initargs=(fn, shared, DieWithParent()))
        try:
            yield from pool.map(_call, jobs, chunksize=4)
        finally:
            pool.shutdown(cancel_futures=True)

    def threads_per_worker(self, workers: int, threads: int) -> int:
        """The workers share this machine's cores (`threads` is for Ray)."""
        return max(1, (os.cpu_count() or 1) // workers)

    def start(self, factory, cpus: int = 1, name: str = "Worker"):
        return factory()


# ------------------------------------------------------------------ Ray


def _run_batch(fn, jobs: list, shared) -> list:
    return [fn(j, shared) for j in jobs]


class RayBackend:
    name = "ray"
    retries_lost_workers = True  # an actor lost with its node: a new one runs on a live node

    def __init__(self, address: str | None = None, workers: int | None = None):
        from .raycluster import connect

        self.ray = connect(address, code_dir=CODE_DIR)  # on the Ray workers' PYTHONPATH
        self.workers = workers
        self._actor_classes: dict = {}

    def slots(self, cpus: int = 1) -> int:
        """As many workers of `cpus` CPUs each as the cluster's live nodes hold, at most `workers`."""
        n = max(1, sum(int(node["Resources"].get("CPU", 0)) // cpus for node in self.ray.nodes() if node["Alive"]))
        return min(n, self.workers) if self.workers else n

    def map(self, fn, jobs: list, shared=None, batch: int | None = None):
        """Yield fn(job, shared) for every job, batch by batch as batches finish (one CPU per batch)."""
        ray = self.ray
        if not jobs:
            return
        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        # a few batches per CPU balance the load; batches of a few jobs keep scheduling cheap
        batch = batch or max(1, min(16, -(-len(jobs) // (4 * cpus))))
        task = ray.remote(num_cpus=1, max_retries=3)(_run_batch)
        shared_ref = ray.put(shared)
        batches = [jobs[i:i + batch] for i in range(0, len(jobs), batch)]
        cap, pending = self.workers or len(batches), []
        while pending or batches:
            while batches and len(pending) < cap:
                pending.append(task.remote(fn, batches.pop(0), shared_ref))
            ready, pending = wait_for_nodes(ray, pending)
            yield from ray.get(ready[0])

    def threads_per_worker(self, workers: int, threads: int) -> int:
        """Each actor reserves `threads` CPUs of its node."""
        return threads

    def start(self, factory, cpus: int = 1, name: str = "Worker"):
        key = (factory, cpus, name)
        if key not in self._actor_classes:
            self._actor_classes[key] = _actor_class(self.ray, factory, cpus, name)
        return _ActorWorker(self.ray, self._actor_classes[key].remote())


def _actor_class(ray, factory, cpus: int, name: str):
    class Actor:
        def __init__(self):
            self.worker = factory()

        @ray.method(num_returns="streaming")
        def run(self, job):
            yield from self.worker.run(job)

        def stop(self) -> None:
            self.worker.close()

    Actor.__name__ = Actor.__qualname__ = f"{name}Actor"  # the actor's process title: ray::<name>Actor
    return ray.remote(num_cpus=cpus, max_restarts=0, max_task_retries=0)(Actor)


def node_timeout_s() -> float:
    return float(os.environ.get("FISHEYE_BEV_RAY_NODE_TIMEOUT_S", RAY_NODE_TIMEOUT_S))


def live_cpus(ray) -> int:
    return sum(int(n["Resources"].get("CPU", 0)) for n in ray.nodes() if n["Alive"])


def wait_for_nodes(ray, refs: list):
    """ray.wait(refs, num_returns=1), but ClusterGone once no live node has had a CPU for
    node_timeout_s() seconds (Ray itself would wait for one forever)."""
    timeout, since = node_timeout_s(), None
    while True:
        ready, rest = ray.wait(refs, num_returns=1, timeout=POLL_S)
        if ready:
            return ready, rest
        if live_cpus(ray) > 0:
            since = None
        elif since is None:
            since = time.monotonic()
        elif time.monotonic() - since >= timeout:
            raise ClusterGone(f"--backend ray: no live Ray node with a CPU for {timeout:g} s; finished work is kept: "
                              f"run the same command again when the cluster is back")


class _ActorWorker:
    def __init__(self, ray, actor):
        self.ray, self.actor = ray, actor
        self.gone = False  # the cluster went away: nothing to stop gracefully

    def run(self, job):
        ray = self.ray
        try:
            stream = self.actor.run.remote(job)
            while True:
                try:
                    wait_for_nodes(ray, [stream])
                except ClusterGone:
                    self.gone = True
                    raise
                try:
                    ref = next(stream)
                except StopIteration:
                    return
                yield ray.get(ref)
        except ray.exceptions.RayError as exc:  # the worker's own exception arrives wrapped (as .cause)
            cause = getattr(exc, "cause", None)
            if isinstance(cause, Exception) and not isinstance(cause, ray.exceptions.RayError):
                raise cause from None
            raise WorkerLost(f"Ray worker lost ({type(exc).__name__})") from None

    def close(self) -> None:
        try:  # let the worker exit cleanly (its temp folder), then free the actor's CPUs
            if not self.gone:
                self.ray.get(self.actor.stop.remote(), timeout=60)
        except Exception:  # noqa: BLE001 - already dead
            pass
        try:
            self.ray.kill(self.actor, no_restart=True)
        except Exception:  # noqa: BLE001 - already dead
            pass
