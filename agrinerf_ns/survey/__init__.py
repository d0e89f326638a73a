"""A farm survey (``agrinerf-survey``): a folder of raw captures in; each processed, trained and counted, as jobs in
this process or as Ray tasks; one table out.

:mod:`~agrinerf_ns.survey.stages` (the three steps of one capture and their records),
:mod:`~agrinerf_ns.survey.intervals` (the count's and the mean temperature's intervals),
:mod:`~agrinerf_ns.survey.table` (the survey table), :mod:`~agrinerf_ns.survey.cli` (the command).
"""
