"""A whole row of a long capture: cut into overlapping segments (:mod:`~agrinerf_ns.row.segments`), each trained
and counted as jobs (:mod:`~agrinerf_ns.row.segment_steps`), their fruit joined across borders (:mod:`~agrinerf_ns.row.join`)
into one yield map (:mod:`~agrinerf_ns.row.yield_map`, :mod:`~agrinerf_ns.row.report`); the command is
:mod:`agrinerf_ns.row.cli` (``agrinerf-row``)."""
