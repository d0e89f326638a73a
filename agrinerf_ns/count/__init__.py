"""Fruit in 3D from a trained run (``agrinerf-count``): detect fruit in rendered views, lift the detections to 3D with
the rendered depth, fuse them across views into fruit, and score the fruit map against a synthetic capture's truth.

One module per job: :mod:`~agrinerf_ns.count.render` (views with depth and rays, cached as ``.npz``),
:mod:`~agrinerf_ns.fruit.blobs` and :mod:`~agrinerf_ns.count.detectors` (fruit masks per view; the default needs only
OpenCV, YOLO is the optional AGPL extra, imported lazily), :mod:`~agrinerf_ns.count.lift` (pixels to a 3D centre and
diameter), :mod:`~agrinerf_ns.count.cluster` (detections to fruit), :mod:`~agrinerf_ns.count.fruit_score` (against the
truth), :mod:`~agrinerf_ns.count.write` (CSV, PLY, map), :mod:`~agrinerf_ns.count.pipeline` (the steps in order),
:mod:`~agrinerf_ns.count.cli` and :mod:`~agrinerf_ns.lab.count_oracle` (a synthetic capture's own frames and true depth as
a render folder, to measure the counting apart from the reconstruction).
"""
