"""Test helpers, imported as ``helpers.<module>`` (``tests/`` is on ``sys.path`` as the folder of ``conftest.py``):

- ``tiny_scene``: the checker-textured sphere (one ray caster), ``look_at`` and ``write_transforms``;
- ``model_scene``: that sphere as a tri-modal dataset, and the shrunk ``agrinerf-lite`` trainer config;
- ``dataset_fixtures``: random-pixel tri-modal dataset folders for dataparser and dataset tests;
- ``process_raw_fixture``: raw captures for ``agrinerf-process``;
- ``tiny_run``: a tiny trained run on disk.
"""
