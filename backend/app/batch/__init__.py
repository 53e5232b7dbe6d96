"""Batch fits on Ray: every photo pair of a folder a task, from one machine to a cluster.

- :mod:`.scheduler`: the driver: the shared job model's jobs (backend/core/pair_jobs.py) submitted, retried
  once, Ctrl+C, progress, catalogue;
- :mod:`.job`: one pair's fit as a task (``backend.app.folder``, the fit command's function, in the
  Ray worker), photos in and result files out as bytes;
- :mod:`.ray_executor`: the only module that imports Ray (the optional ``cluster`` extra);
- :mod:`.output`: the results folder DIR, written whole or not at all; :mod:`.catalogue`: its table.

The command line is backend/app/cli/batch.py. Imports: core, fit (the fit command's function), nothing
of cli; the Blender extension leaves this package out (build.py).
"""
