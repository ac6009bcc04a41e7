"""The Ray backend of the render driver (`generate --backend ray`).

One actor per Blender worker process: the actor owns a `blender_scripts.worker` subprocess
(driver.WorkerProcess, the local pool's protocol) and streams its "frame" messages back, so the
driver writes the manifest and moves one progress bar. Each actor reserves `threads` CPUs
(num_cpus), so a node runs cores // threads of them. An actor that dies (its process, its
Blender or its node) surfaces as driver.WorkerLost: the driver requeues the task's unfinished
frames and starts a new actor, which Ray places on a node that is still alive.
"""

from __future__ import annotations

from common.raycluster import connect

from .config import REPO
from .driver import WorkerFailed, WorkerLost, WorkerProcess


def _actor_class(ray, threads: int):
    class RenderActor:
        def __init__(self):
            self.worker = WorkerProcess()

        @ray.method(num_returns="streaming")
        def run(self, task: dict):
            yield from self.worker.run(task)

        def stop(self) -> None:
            self.worker.close()

    return ray.remote(num_cpus=threads, max_restarts=0, max_task_retries=0)(RenderActor)


class RayPool:
    """The actors of one render run; `new_worker()` gives a driver slot (run(task)/close())."""

    def __init__(self, address: str | None, threads: int = 1, workers: int | None = None):
        self.ray = ray = connect(address, code_dir=REPO)
        self.actor_cls = _actor_class(ray, threads)
        # as many actors as the cluster's nodes hold (CPUs // threads each), at most `workers`
        self.slots = max(1, sum(int(n["Resources"].get("CPU", 0)) // threads for n in ray.nodes() if n["Alive"]))
        if workers:
            self.slots = min(self.slots, workers)

    def new_worker(self):
        return _Slot(self.ray, self.actor_cls.remote())


class _Slot:
    def __init__(self, ray, actor):
        self.ray, self.actor = ray, actor

    def run(self, task: dict):
        ray = self.ray
        try:
            for ref in self.actor.run.remote(task):
                yield ray.get(ref)
        except ray.exceptions.RayError as exc:  # a task's own exception arrives wrapped (as .cause)
            cause = getattr(exc, "cause", None)
            if isinstance(cause, WorkerFailed):
                raise WorkerFailed(cause.message, cause.trace) from None
            raise WorkerLost(f"{task['scene']}: Ray worker lost ({type(exc).__name__})") from None

    def close(self) -> None:
        try:  # let Blender exit cleanly (its temp folder), then free the actor's CPUs
            self.ray.get(self.actor.stop.remote(), timeout=60)
        except Exception:  # noqa: BLE001 - already dead
            pass
        try:
            self.ray.kill(self.actor, no_restart=True)
        except Exception:  # noqa: BLE001 - already dead
            pass
