"""A Dask scheduler and worker processes started as separate programs on 127.0.0.1 (for tests and
benchmarks: a cluster as a real one is, with no shared process or nanny)."""

from __future__ import annotations

import os
import sys
import time

from wmr.engine.executors import WORKER_ENV

__all__ = ["LoopbackCluster"]


class LoopbackCluster:
    """A Dask scheduler and ``workers`` worker processes started as separate programs on
    127.0.0.1, as on a real cluster (``dask scheduler`` and ``dask worker``: one process of one
    thread each, no nanny); ``address`` is the scheduler's.  For tests and benchmarks; on a real
    cluster start them by hand (docs/scaling.md).  Use as a context manager."""

    def __init__(self, folder, workers: int = 2, timeout: float = 120.0):
        import json
        import subprocess
        from pathlib import Path

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.file = folder / "scheduler.json"
        env = {**os.environ, **WORKER_ENV}
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
        py = sys.executable
        self.scheduler = subprocess.Popen(
            [py, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(self.file)], **quiet)  # fmt: skip
        self.workers = []
        try:
            t0 = time.monotonic()
            while not (self.file.exists() and self.file.read_text().strip()):
                if time.monotonic() - t0 > timeout or self.scheduler.poll() is not None:
                    raise RuntimeError("the Dask scheduler did not start")
                time.sleep(0.1)
            self.address = json.loads(self.file.read_text())["address"]
            self.workers = [subprocess.Popen(
                [py, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(self.file),
                 "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host", "127.0.0.1",
                 "--local-directory", str(folder / f"worker-{i}")], **quiet)
                for i in range(workers)]  # fmt: skip
            from distributed import Client

            with Client(self.address, timeout=timeout) as client:
                client.wait_for_workers(workers, timeout=timeout)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
