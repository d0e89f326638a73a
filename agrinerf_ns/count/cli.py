"""``agrinerf-count --config RUN/config.yml --out DIR [--truth RAW_CAPTURE]``: fruit in 3D from a trained run, counted
in the sampled field (``--path field``) or detected in rendered views and lifted (``--path views``); by default
(``--path auto``) the one that counted best on runs of its kind (``agrinerf_ns.count.auto_path``)."""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Literal, Optional, Tuple

import tyro

from agrinerf_ns.atomic import OutputExistsError
from agrinerf_ns.count.auto_path import choose_plan
from agrinerf_ns.count.body_count import run_body_count
from agrinerf_ns.count.field_count import FieldCountConfig, run_field_count
from agrinerf_ns.count.pipeline import CONSOLE, CountConfig, CountResult, print_summary, run_count
from agrinerf_ns.count.render import CountInputError, WorldFrame
from agrinerf_ns.count.row_range import check_range
from agrinerf_ns.run_loading import trained_run_config


@dataclass
class CountArgs:
    """Count fruit in 3D from a trained run: sample the field on a grid and group the voxels that stand out in
    temperature (or colour) into fruit (--path field), or render every camera, detect fruit per view, lift the
    detections with the rendered depth and fuse them (--path views); writes fruits.csv, fruits.ply, fruit_map.png
    and count.json (and score.md against a synthetic capture's truth)."""

    out: Path
    """Output folder (written to a temporary sibling, then renamed into place)."""
    config: Optional[Path] = None
    """The run's config.yml (outputs/<name>/<method>/<time>/config.yml) or its folder."""
    path: Literal["auto", "views", "field", "fruit", "bodies"] = "auto"
    """auto: what counted best on runs of this kind: a run with a fruit head, its fruit channel in the views; else RGB
    views placed by their rays where the RGB frames are lit, the field's temperature where they are dark or absent
    (docs/count.md); views: detect in rendered views and lift
    (--renders: always); field: count in the sampled field, in 3D; fruit: count in 3D where the run's fruit head
    (trained from the frames' fruit masks) says fruit; bodies: the thermal fruit bodies the data stage placed across
    the dark frames with their poses (the dataset's fruit_bodies.json: no field needed, --data DATASET or the run's
    dataset)."""
    data: Optional[Path] = None
    """With --path bodies: the processed dataset to count (instead of --config)."""
    renders: Optional[Path] = None
    """Instead of --config: a render folder written by an earlier count (OUT/renders), to re-detect without rendering."""
    truth: Optional[Path] = None
    """A synthetic raw capture (agrinerf-synth) whose truth/fruits.json scores the count."""
    overwrite: bool = False
    """Replace --out when it exists."""
    splits: Tuple[Literal["train", "eval"], ...] = ("train", "eval")
    """The run's cameras to render and count in (training and held-out views)."""
    save_renders: bool = True
    """Keep the rendered views under OUT/renders (npz per view)."""
    count: Annotated[CountConfig, tyro.conf.arg(name="")] = field(default_factory=CountConfig)
    """Detection (views), clustering and scoring options."""
    field: FieldCountConfig = dataclasses.field(default_factory=FieldCountConfig)
    """The field path's options."""


def main(args: CountArgs) -> CountResult:
    try:
        check_range(args.count.max_range)  # before any run is loaded
        if args.path == "bodies":
            return count_bodies(args)
        if args.path in ("field", "fruit") and args.renders is None:
            if args.config is None:
                raise ValueError("give --config RUN/config.yml (or the run folder)")
            settings = replace(args.field, source="fruit") if args.path == "fruit" else args.field
            return run_field_count(args.config, args.out, settings, args.truth, args.overwrite, args.count)[0]
        config = trained_run_config(args.config) if args.config is not None else None
        count, loaded = args.count, None
        if args.path == "auto" and config is not None:
            from agrinerf_ns.run_loading import load_run  # Nerfstudio is imported only when a run is loaded

            loaded = load_run(config)  # loaded once: the plan reads its model, the chosen path counts it
            plan = choose_plan(loaded.pipeline.model, loaded.dataset_dir)
            CONSOLE.print(f"Counting by the {plan.path} path: {plan.why}", soft_wrap=True)
            if plan.path == "bodies":
                return count_bodies(replace(args, data=loaded.dataset_dir), config)
            if plan.path == "field":
                return run_field_count(config, args.out, args.field, args.truth, args.overwrite, count, loaded)[0]
            count = replace(count, cluster=replace(count.cluster, triangulate=plan.triangulate))
        return run_count(
            args.out, count, config, args.renders, args.truth, args.overwrite, args.save_renders, args.splits, loaded
        )
    except (CountInputError, OutputExistsError, FileExistsError, FileNotFoundError, ValueError) as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(2)


def count_bodies(args: CountArgs, config: Optional[Path] = None) -> CountResult:
    """``--path bodies``: the dataset's thermal bodies (``--data``, else the dataset of the run at ``--config``)."""
    frame = None
    if args.config is not None:
        config = config or trained_run_config(args.config)
        frame = WorldFrame.read(config.parent / "dataparser_transforms.json")
    data = args.data
    if data is None:
        if config is None:
            raise ValueError("--path bodies: give --data DATASET (or the run's --config)")
        from agrinerf_ns.run_loading import run_dataset  # the config alone: the field is not needed

        data = run_dataset(config)
    if data is None:
        raise ValueError(f"{config}: the run does not name its dataset folder; give --data DATASET")
    result = run_body_count(data, args.out, args.count, args.truth, args.overwrite, frame)
    print_summary(args.out, result, args.count.max_range)
    return result


def entrypoint() -> None:
    """Console script entry point."""
    tyro.extras.set_accent_color("bright_yellow")
    main(tyro.cli(CountArgs))


if __name__ == "__main__":
    entrypoint()
