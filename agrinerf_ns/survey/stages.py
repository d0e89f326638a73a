"""The three steps of one capture of a survey, each a job, and where each writes.

::

    OUT/captures/<capture>/data/                      the processed dataset (agrinerf-process)
    OUT/captures/<capture>/train/<method>/run/        the ns-train run (config.yml, checkpoints); train_run.json
    OUT/captures/<capture>/train/<method>.train.log   its log
    OUT/captures/<capture>/count/                     agrinerf-count's outputs (with score.md against a truth)
    OUT/captures/<capture>/<stage>.json               a finished step's record (wall time, and the count's figures)

Each step writes only its own capture's folder, its outputs atomically and its record last: a survey that is run
again skips the steps that have a record and redoes the others.
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

from agrinerf_ns.count.pipeline import CountConfig
from agrinerf_ns.dataset_format import TRANSFORMS
from agrinerf_ns.orchestrate.jobs import Job, Resources
from agrinerf_ns.process.capture_to_dataset import ProcessConfig

STAGES = ("process", "train", "count")
CAPTURES_DIR = "captures"
TRAIN_EXPERIMENT = "train"

Step = Tuple[Callable[..., Any], Tuple[Any, ...], Resources, Optional[Path]]
"""A step's function, its arguments, the resources it holds and its own log (None: none)."""


@dataclass(frozen=True)
class SurveySettings:
    """How every capture of a survey is processed, trained and counted."""

    method: str = "agrinerf-lite"
    """The ``ns-train`` method (preset) each capture is trained with."""
    steps: int = 30000
    """Training steps per capture."""
    rays_per_batch: int = 4096
    """Training rays per batch."""
    train_args: Tuple[str, ...] = ()
    """Further ``ns-train`` options of the method (before the dataparser)."""
    process: ProcessConfig = field(default_factory=ProcessConfig)
    count: CountConfig = field(default_factory=CountConfig)
    jackknife_groups: int = 10
    """Interleaved groups of views of the count's jackknife interval (:mod:`agrinerf_ns.survey.intervals`)."""


@dataclass(kw_only=True)
class JobOptions:
    """The command-line options ``agrinerf-survey`` and ``agrinerf-row`` share: how each capture (or row segment) is
    trained and counted, and how its jobs run."""

    method: str = "agrinerf-lite"
    """``ns-train`` method (preset) each capture or segment is trained with."""
    steps: int = 30000
    """Training steps per capture or segment."""
    rays_per_batch: int = 4096
    """Training rays per batch."""
    train_args: str = ""
    """Further ``ns-train`` method options in one string, e.g. ``--train-args="--pipeline.model.final-resolution 128"``."""
    ray: Optional[str] = None
    """Run the jobs as Ray tasks (the ``[ray]`` extra): ``local`` starts Ray on this machine, ``auto`` joins the
    cluster this machine belongs to, or a cluster address. OUT and the inputs must be on a filesystem every node
    sees. None: one job after another in this process."""
    cpus_per_task: Optional[int] = None
    """CPU cores (and threads) each job holds; None: one per job with --ray, threads unchanged without."""
    gpus_per_train: float = 0.0
    """GPUs each training and counting job holds with --ray (1 on a GPU cluster)."""
    memory_gb_per_train: Optional[float] = None
    """Memory Ray reserves for each training and counting job (GiB; None: none reserved)."""
    retries: int = 1
    """Further attempts of a step that fails or whose worker dies, before it is reported failed."""
    ray_cpus: Optional[int] = None
    """With --ray local: the CPUs Ray may use (None: all of this machine's)."""
    jackknife_groups: int = 10
    """Interleaved groups of views of each count's interval (a delete-a-group jackknife)."""
    process: ProcessConfig = field(default_factory=lambda: ProcessConfig(show_progress=False))
    """Processing options (as ``agrinerf-process``)."""
    count: CountConfig = field(default_factory=CountConfig)
    """Detection, clustering and scoring options of every count (as ``agrinerf-count``; --count.max-range keeps the
    row the rig drove)."""

    def settings(self, process: Optional[ProcessConfig] = None) -> "SurveySettings":
        """The steps' settings (``process``: in place of :attr:`process`)."""
        return SurveySettings(self.method, self.steps, self.rays_per_batch, tuple(shlex.split(self.train_args)),
                              self.process if process is None else process, self.count, self.jackknife_groups)  # fmt: skip

    def resources(self) -> Tuple[Resources, Resources]:
        """What a light and a heavy step hold (:func:`step_resources`)."""
        return step_resources(self.cpus_per_task, self.ray, self.gpus_per_train, self.memory_gb_per_train)

    def executor_options(self) -> Dict[str, Any]:
        """Keyword options of :func:`agrinerf_ns.orchestrate.executors.executor_for` beside the address."""
        return {"num_cpus": self.ray_cpus} if self.ray else {}


@dataclass(frozen=True)
class CaptureFolders:
    """Where one capture's steps write."""

    root: Path

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def train_root(self) -> Path:
        return self.root / TRAIN_EXPERIMENT

    def run_config(self, method: str) -> Path:
        return self.train_root / method / "run" / "config.yml"

    def train_log(self, method: str) -> Path:
        return self.train_root / f"{method}.train.log"

    @property
    def train_record(self) -> Path:
        return self.train_root / "train_run.json"

    @property
    def count(self) -> Path:
        return self.root / "count"

    def record(self, stage: str) -> Path:
        return self.root / f"{stage}.json"


def capture_folders(out: Path, capture: str) -> CaptureFolders:
    """``OUT/captures/<capture>``."""
    return CaptureFolders(Path(out) / CAPTURES_DIR / capture)


def read_record(folders: CaptureFolders, stage: str) -> Optional[Dict[str, Any]]:
    """A finished step's record, None when the step has not finished."""
    path = folders.record(stage)
    return json.loads(path.read_text()) if path.is_file() else None


def write_record(folders: CaptureFolders, stage: str, record: Dict[str, Any]) -> Dict[str, Any]:
    """Write a finished step's record (atomically, last: its presence marks the step done); returns it."""
    path = folders.record(stage)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(record, indent=1) + "\n")
    tmp.replace(path)
    return record


def process_step(raw: Path, folders: CaptureFolders, settings: SurveySettings, *_: Any) -> Dict[str, Any]:
    """Job: the raw capture to its dataset (replacing one left by an attempt that wrote no record)."""
    from agrinerf_ns.process import process_capture

    start = time.perf_counter()
    config = dataclasses.replace(settings.process, overwrite=True, show_progress=False)
    process_capture(raw, folders.data, config)
    return write_record(folders, "process", {"wall_s": time.perf_counter() - start})


def train_step(folders: CaptureFolders, settings: SurveySettings, *_: Any) -> Dict[str, Any]:
    """Job: train the survey's method on the capture's dataset (a run folder left without a record is removed)."""
    from agrinerf_ns.ns_commands import ns_train

    shutil.rmtree(folders.train_root / settings.method, ignore_errors=True)
    run = ns_train(settings.method, folders.data / TRANSFORMS, folders.root, TRAIN_EXPERIMENT,
                   max_steps=settings.steps, rays_per_batch=settings.rays_per_batch,
                   extra_args=settings.train_args)  # fmt: skip
    run.save(folders.train_record)
    return write_record(folders, "train", {"wall_s": run.wall_s, "config": str(run.config), "steps": settings.steps,
                                            "peak_rss_mb": run.peak_rss_mb})  # fmt: skip


def count_step(raw: Path, folders: CaptureFolders, settings: SurveySettings, *_: Any) -> Dict[str, Any]:
    """Job: count the trained run's fruit (scored against ``raw``'s truth where it has one), with intervals."""
    from agrinerf_ns.count.fruit_score import FRUITS_JSON
    from agrinerf_ns.count.pipeline import run_count
    from agrinerf_ns.count.render import load_renders
    from agrinerf_ns.survey.intervals import count_interval

    start = time.perf_counter()
    truth = raw if (raw / FRUITS_JSON).is_file() else None
    result = run_count(folders.count, settings.count, folders.run_config(settings.method), truth=truth,
                       overwrite=True, save_renders=True)  # fmt: skip
    renders = load_renders(folders.count / "renders")
    low, high = count_interval(len(result.fruit), result.detections, renders, settings.count.cluster,
                               settings.jackknife_groups)  # fmt: skip
    record = count_record(result, start, (low, high))
    record["jackknife_groups"] = min(settings.jackknife_groups, len(renders.views))
    record["views"] = len(renders.views)
    return write_record(folders, "count", record)


def count_record(result: Any, start: float, interval: Tuple[float, float]) -> Dict[str, Any]:
    """A count step's record: wall time since ``start`` (``time.perf_counter``), the fruit and their ``interval``,
    the mean temperature with its half-width, and the score against a truth (non-finite figures as None, for JSON)."""
    from agrinerf_ns.survey.intervals import finite_or_none, mean_temperature

    temperature, temperature_half = mean_temperature(result.fruit)
    score = None if result.score is None else result.score.as_dict()
    return {
        "wall_s": time.perf_counter() - start,
        "fruit": len(result.fruit),
        "fruit_interval": [finite_or_none(interval[0]), finite_or_none(interval[1])],
        "temperature_c": finite_or_none(temperature),
        "temperature_half_c": finite_or_none(temperature_half),
        "score": None if score is None else {k: finite_or_none(v) if isinstance(v, float) else v
                                             for k, v in score.items()},
    }  # fmt: skip


def step_resources(
    cpus_per_task: Optional[int], ray: Optional[str], gpus_per_train: float, memory_gb_per_train: Optional[float]
) -> Tuple[Resources, Resources]:
    """What a light step (processing, cutting) and a heavy one (training, counting) hold: ``cpus_per_task`` cores
    each (one per job with ``ray``, the threads unchanged without), and the heavy ones the GPUs and memory asked."""
    cpus = cpus_per_task if cpus_per_task is not None or ray is None else 1
    memory = None if memory_gb_per_train is None else int(memory_gb_per_train * 1024)
    return Resources(cpus=cpus), Resources(cpus=cpus, gpus=gpus_per_train, memory_mb=memory)


def chained_jobs(
    name: str, folders: CaptureFolders, steps: Dict[str, Step], order: Sequence[str], retries: int
) -> List[Job]:
    """The steps of ``order`` that have no record in ``folders``, each a job (``name:stage``) after the one before."""
    jobs: List[Job] = []
    previous: Tuple[str, ...] = ()
    for stage in order:
        if read_record(folders, stage) is not None:
            continue
        fn, fn_args, resources, log = steps[stage]
        key = f"{name}:{stage}"
        jobs.append(Job(key, fn, fn_args, folders.root, resources, previous, log, retries))
        previous = (key,)
    return jobs
