"""Many items at once: ``observe``, ``tune``, ``analyze`` and ``simulate`` over a fleet's
recordings or a study's grid, on all local cores or a Dask cluster.

An item is one run of a single-item command (the same code ``elastic-pm-dyn observe`` ...
runs), written into its own folder under the batch's output; the batch adds the item
folders' summary figures into one results table and overview plots. Layout, bottom to top:

- :mod:`~elastic_pm_dyn.fleet.items`: what an item is, discovery (folder, glob, manifest)
- :mod:`~elastic_pm_dyn.fleet.study`: a study's grid or random sample -> simulate items
- :mod:`~elastic_pm_dyn.fleet.store`: an item's folder, its record, complete or not, its attempts
- :mod:`~elastic_pm_dyn.fleet.timeouts`: how long an item may run
- :mod:`~elastic_pm_dyn.fleet.verdict`: whether a finished command estimated anything
- :mod:`~elastic_pm_dyn.fleet.watchdog`: an item's time limit inside its worker (Dask)
- :mod:`~elastic_pm_dyn.fleet.runners`: run one item in a worker
- :mod:`~elastic_pm_dyn.fleet.checks`: the items' options checked before any worker starts
- :mod:`~elastic_pm_dyn.fleet.warm`: a worker's warm-up (the job's imports and kernels)
- :mod:`~elastic_pm_dyn.fleet.pool`: the local pool, a supervisor of its own worker processes
- :mod:`~elastic_pm_dyn.fleet.engines`: the local pool or Dask distributed
- :mod:`~elastic_pm_dyn.fleet.progress`, :mod:`~elastic_pm_dyn.fleet.table`, :mod:`~elastic_pm_dyn.fleet.live`,
  :mod:`~elastic_pm_dyn.fleet.plots`: what the user watches and reads
- :mod:`~elastic_pm_dyn.fleet.lock`: one batch at a time per output folder
- :mod:`~elastic_pm_dyn.fleet.api`: ``epd.batch(...)``; :mod:`~elastic_pm_dyn.fleet.cli`: ``elastic-pm-dyn batch``

(Named ``fleet``, not ``batch``: a sub-package ``elastic_pm_dyn.batch`` would replace the
public function ``epd.batch`` as soon as it is imported.)
"""
