"""2D fruit vision: how fruit are found in one image, shared by the data stage (fruit masks from the captured frames,
:mod:`agrinerf_ns.process.fruit_mask_makers`), the counter (:mod:`agrinerf_ns.count`) and the detector
(:mod:`agrinerf_ns.detect`), and importing none of them.

One module per rule: :mod:`~agrinerf_ns.fruit.colour_score` (a pixel's fruit colour), :mod:`~agrinerf_ns.fruit.contrast`
(a value standing out from its surroundings), :mod:`~agrinerf_ns.fruit.blobs` (fruit-sized contrast blobs of a rendered
view), :mod:`~agrinerf_ns.fruit.regions` (the regions of a rendered fruit probability),
:mod:`~agrinerf_ns.fruit.thermal_blobs` (fruit-sized blobs of a thermal frame), :mod:`~agrinerf_ns.fruit.ellipse` (a
round fruit's pixels from its box) and :mod:`~agrinerf_ns.fruit.yolo` (a YOLO box predictor; Ultralytics is the optional
AGPL-3.0 extra, imported only inside its functions). :mod:`~agrinerf_ns.fruit.view` states what these read of a
rendered view.
"""
