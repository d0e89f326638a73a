"""Many runs at once: a benchmark grid or a farm survey as jobs, run in this process or as Ray tasks.

:mod:`~agrinerf_ns.orchestrate.jobs` (jobs, their resources, the driver loop and the in-process executor; no Ray),
:mod:`~agrinerf_ns.orchestrate.ray_executor` (the same jobs as Ray tasks: the one module that imports Ray, the
optional ``[ray]`` extra), :mod:`~agrinerf_ns.orchestrate.executors` (``executor_for``: the one or the other),
:mod:`~agrinerf_ns.lab.bench_grid` (``agrinerf-bench`` runs as jobs). The survey command is
:mod:`agrinerf_ns.survey`.
"""
