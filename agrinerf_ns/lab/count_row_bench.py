"""Counting in ``agrinerf-bench --profile count``: each finished run counted as the #60 tables count by hand, and the
truth-mask oracle of each capture beside it::

    OUT/count-row/<scene>/<method key>/capture/   agrinerf-count --config RUN/config.yml --path views --source fruit
                                                  --truth RAW (the renders kept under renders/)
    OUT/count-row/<scene>/<method key>/row/       agrinerf-count --renders .../capture/renders --source fruit
                                                  --no-save-renders --max-range R --truth RAW
    OUT/count-row/<scene>/oracle/row/             python -m agrinerf_ns.lab.count_oracle --raw RAW --data DS --out O
                                                  --fruit true, then counted as the row (O removed after)
    OUT/count-row/<scene>/bodies/row/             agrinerf-count --path bodies --data DS --max-range R --truth RAW
                                                  (where the dataset holds fruit bodies: the lit masks' and the
                                                  thermal camera's, placed by the poses; no field)

``R`` is the profile's ``row_range`` of the scene kind. A count already written is kept (the bench resumes). The
seeds-by-lightings table of every row count under ``OUT`` (and ``OUT/seed-<S>/``) is ``OUT/counts.md``
(:func:`write_bench_tables`; ``python benchmarks/count_fruit_table.py --bench OUT`` writes it again)."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING, List, Mapping, Optional, Sequence, Tuple

from agrinerf_ns.dataset_format import FRUIT_BODIES
from agrinerf_ns.lab.count_row_tables import (
    COLUMNS,
    LIGHTING_ORDER,
    MEASURES,
    Row,
    read_row,
    seed_summary,
    seed_table,
    write_rows,
)
from agrinerf_ns.lab.layout import BenchLayout, scene_folders, split_scene
from agrinerf_ns.lab.profiles import BenchProfile

if TYPE_CHECKING:
    from agrinerf_ns.count.pipeline import CountConfig

ROW_DIR = "count-row"
ORACLE = "oracle"
BODIES = "bodies"
LABELS = {ORACLE: "oracle (truth masks, true depth)", BODIES: "fruit bodies (no field)"}
"""Row labels of the counts that are not a bench method's."""
CAPTURE, ROW = "capture", "row"
SEED_PREFIX = "seed-"
"""``agrinerf-bench --seeds``: each scene seed's benchmark folder is ``OUT/seed-<S>``."""


def seed_out(out: Path, seed: int) -> Path:
    """The benchmark folder of scene seed ``seed`` under ``agrinerf-bench --seeds``."""
    return Path(out) / f"{SEED_PREFIX}{seed}"


def row_range(profile: BenchProfile, scene: str) -> float:
    """The profile's ``--max-range`` for ``scene`` (``<kind>-<lighting>``); ValueError naming the kind without one."""
    kind = split_scene(scene)[0]
    if kind not in profile.row_range:
        raise ValueError(f"the profile has no row range for {kind!r} scenes (it has: {', '.join(profile.row_range)})")
    return profile.row_range[kind]


def count_row_bench(
    layout: BenchLayout, scenes: Sequence[str], methods: Mapping[str, str], profile: BenchProfile
) -> None:
    """Count every finished run of ``methods`` (bench key -> ns-train method) in ``scenes`` on its whole capture and
    on the row, and each capture's oracle on the row; counts already written are kept."""
    from agrinerf_ns.count.render import CountInputError
    from agrinerf_ns.lab.count_bench import CONSOLE

    for scene in scenes:
        raw, data = layout.scene(scene)
        max_range = row_range(profile, scene)
        root = Path(layout.out) / ROW_DIR / scene
        if not (root / ORACLE / ROW / "count.json").is_file() and (raw / "truth" / "depth").is_dir():
            CONSOLE.print(f"counting the truth-mask oracle: {scene}")
            _count_oracle(raw, data, root / ORACLE, max_range)
        if not (root / BODIES / ROW / "count.json").is_file() and (data / FRUIT_BODIES).is_file():
            CONSOLE.print(f"counting the fruit bodies: {scene}")
            from agrinerf_ns.count.body_count import run_body_count

            run_body_count(data, root / BODIES / ROW, _fruit_config(max_range), raw, overwrite=True)
        for key, config in layout.finished_runs(scene, methods).items():
            if (root / key / ROW / "count.json").is_file():
                continue
            CONSOLE.print(f"counting fruit: {scene} {key}, the whole capture and the row within {max_range:g} m")
            try:
                _count_run(config, raw, root / key, max_range)
            except CountInputError as err:  # a run without a fruit head (a stock model)
                CONSOLE.print(f"not counted: {scene} {key}: {err}", soft_wrap=True)


def _fruit_config(max_range: Optional[float]) -> "CountConfig":
    """The fruit channel in the views (``--source fruit``), counted within ``max_range`` (None: the whole capture)."""
    from agrinerf_ns.count.detectors import DetectorConfig
    from agrinerf_ns.count.pipeline import CountConfig

    return CountConfig(detect=DetectorConfig(source="fruit"), max_range=max_range)


def _count_run(config: Path, raw: Path, folder: Path, max_range: float) -> None:
    """``agrinerf-count --path views --source fruit`` on the run (renders kept), then the row from those renders."""
    from agrinerf_ns.count.pipeline import run_count
    from agrinerf_ns.run_loading import trained_run_config

    capture = folder / CAPTURE
    if not (capture / "count.json").is_file():
        run_count(capture, _fruit_config(None), trained_run_config(config), truth=raw, overwrite=True)
    run_count(folder / ROW, _fruit_config(max_range), renders_dir=capture / "renders", truth=raw, overwrite=True,
              save_renders=False)  # fmt: skip


def _count_oracle(raw: Path, data: Path, folder: Path, max_range: float) -> None:
    """The truth's fruit pixels and the true depth (``count_oracle --fruit true``) counted on the row."""
    from agrinerf_ns.count.pipeline import run_count
    from agrinerf_ns.count.render import save_renders
    from agrinerf_ns.lab.count_oracle import oracle_renders

    renders = folder / "renders"
    shutil.rmtree(renders, ignore_errors=True)
    save_renders(oracle_renders(raw, data, "reprojected", "true"), renders)
    try:
        run_count(folder / ROW, _fruit_config(max_range), renders_dir=renders, truth=raw, overwrite=True,
                  save_renders=False)  # fmt: skip
    finally:
        shutil.rmtree(renders, ignore_errors=True)  # made again from the capture in a minute


def bench_row_folders(out: Path) -> List[Tuple[str, Path, Path]]:
    """(label, row count folder, raw capture) of every row count in the benchmark folder ``out`` and its
    ``seed-<S>`` folders: the label is the bench method key, or the oracle's or the bodies' (:data:`LABELS`)."""
    found = []
    roots = [Path(out), *sorted(p for p in Path(out).glob(f"{SEED_PREFIX}*") if p.is_dir())]
    for root in roots:
        for count_json in sorted((root / ROW_DIR).glob(f"*/*/{ROW}/count.json")):
            folder = count_json.parent
            scene, key = folder.parent.parent.name, folder.parent.name
            label = LABELS.get(key, key)
            found.append((label, folder, scene_folders(root / "scenes", scene).raw))
    return found


def write_bench_tables(out: Path, header: str, reporting_from: int = 100) -> List[Row]:
    """``OUT/counts.csv`` (a row per row count), ``OUT/summary.csv`` (mean, standard deviation, least and most over
    seeds per scene, lighting, seed role and row) and ``OUT/counts.md`` (:func:`seed_table`) from every row count
    under ``out``; FileNotFoundError when there is none."""
    folders = bench_row_folders(out)
    if not folders:
        raise FileNotFoundError(f"{out}: no row counts ({ROW_DIR}/<scene>/<method>/{ROW}/count.json, agrinerf-bench "
                                "--profile count writes them)")  # fmt: skip
    out = Path(out)
    rows = [read_row(label, folder, reporting_from, raw) | {"folder": str(folder.relative_to(out))}
            for label, folder, raw in folders]  # fmt: skip
    rows.sort(key=lambda r: (r["scene"], LIGHTING_ORDER.get(str(r["lighting"]), 9), r["seed"], r["label"]))
    write_rows(out / "counts.csv", rows, COLUMNS)
    summary = seed_summary(rows)
    if len({r["scene"] for r in rows}) > 1:  # and per lighting over every scene (scene "all")
        summary += seed_summary(rows, pool_scenes=True)
    extra = [f"{m}_{k}" for m in MEASURES for k in ("sd", "min", "max")]
    write_rows(out / "summary.csv", summary, ["scene", "lighting", "role", "label", "runs", "seeds", *MEASURES, *extra])
    (out / "counts.md").write_text(seed_table(rows, header, reporting_from))
    return rows
