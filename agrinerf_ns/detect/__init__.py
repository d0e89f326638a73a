"""Downstream fruit detection on rendered views (the paper's Tables III and IV).

Scoring (:mod:`agrinerf_ns.detect.box_metrics`, :mod:`agrinerf_ns.detect.boxes`) is plain NumPy and independent of any
detector. The detector (:mod:`agrinerf_ns.detect.detector`) wraps Ultralytics YOLOv8, which is AGPL-3.0 and an
optional extra: ``pip install agrinerf-ns[detect]`` or ``scripts/install_detect.sh``. Nothing here imports Ultralytics
at module level.
"""
