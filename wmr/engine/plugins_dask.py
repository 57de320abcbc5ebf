"""Plugins on a Dask cluster: the driver's plugins loaded on the scheduler and on every worker,
present and future.

``DaskEngine`` registers a :class:`PluginLoader` (a Dask ``WorkerPlugin``) and a
:class:`SchedulerLoader` when the driver has loaded plugins (``wmr.plugins.loaded``): Dask runs
the first's ``setup`` on each worker that joins, restarted ones included, and the second's
``start`` on the scheduler, which unpickles the task graph (a job's settings are instances of the
plugin's ``Settings``).  The files' contents travel with them (``wmr.plugins.WorkerLoader``), so
a process whose working folder and ``sys.path`` do not hold the file imports it all the same.
"""

from __future__ import annotations

import tempfile

from distributed.diagnostics.plugin import SchedulerPlugin, WorkerPlugin

from wmr import plugins

__all__ = ["PluginLoader", "SchedulerLoader", "ship"]


class PluginLoader(WorkerPlugin):
    """The Dask face of :class:`wmr.plugins.WorkerLoader`."""

    name = "wmr-plugins"

    def __init__(self, loaded):
        self.loader = plugins.WorkerLoader(loaded)

    def setup(self, worker):
        self.loader.setup(worker)


class _Folder:
    def __init__(self):
        self.local_directory = tempfile.mkdtemp(prefix="wmr-scheduler-")


class SchedulerLoader(SchedulerPlugin):
    """The plugins on the scheduler (in a folder of its own), before it unpickles a task."""

    name = "wmr-plugins-scheduler"

    def __init__(self, loaded):
        self.loader = plugins.WorkerLoader(loaded)

    async def start(self, scheduler):
        self.loader.setup(_Folder())


def ship(client) -> None:
    """Register the driver's plugins on ``client``'s scheduler and workers (nothing without
    plugins)."""
    loaded = plugins.loaded()
    if loaded:
        client.register_plugin(SchedulerLoader(loaded), name=SchedulerLoader.name)
        client.register_plugin(PluginLoader(loaded), name=PluginLoader.name)
