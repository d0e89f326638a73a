"""Benchmark grids and surveys as jobs: the driver loop in this process, then on a real local Ray (2 CPUs, no
dashboard): a killed worker's run retried and kept once, an interrupted driver resumed, a survey of three synthetic
captures with one broken capture. Ray stays out of everything else (checked in a fresh interpreter)."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Dict, Iterator, List

import pytest

from agrinerf_ns.lab import bench_grid, results
from agrinerf_ns.lab.layout import BenchLayout, experiment_folder, train_record
from agrinerf_ns.lab.profiles import BenchProfile
from agrinerf_ns.orchestrate.jobs import (
    DRIVER_LOCK,
    FolderInUse,
    Job,
    LocalExecutor,
    Resources,
    attempts,
    driver_lock,
    failures_markdown,
    run_jobs,
)

SCENE = "orchard-dark"
PROFILE = BenchProfile(views=8, width=64, height=48, steps={"agrinerf-lite": 24}, evaluations=2, rays_per_batch=128,
                       scenes=(SCENE,))  # fmt: skip
"""The tiny scene and a short agrinerf-lite run: two checkpoints (saved at steps 12 and 23, reported as 13 and 24)."""


def test_plugin_method_configs_and_commands_import_no_ray() -> None:
    code = (
        "import sys\n"
        "import agrinerf_ns, agrinerf_ns.dataparsers.agrinerf_dataparser, agrinerf_ns.method_configs.agrinerf_methods\n"
        "import agrinerf_ns.lab.cli, agrinerf_ns.survey.cli, agrinerf_ns.lab.bench_grid\n"
        "from nerfstudio.configs.method_configs import all_methods\n"
        "assert 'agrinerf-lite' in all_methods\n"
        "print(sorted(m for m in sys.modules if m == 'ray' or m.startswith('ray.')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def _double(x: int) -> int:
    return 2 * x


def _add(x: int, previous: int) -> int:
    return x + previous


def _fail(message: str) -> None:
    raise RuntimeError(message)


def test_jobs_wait_for_their_inputs_and_a_failure_skips_its_dependents(tmp_path: Path) -> None:
    jobs = [
        Job("a", _double, (3,), tmp_path / "a"),
        Job("b", _add, (1,), tmp_path / "b", after=("a",)),
        Job("bad", _fail, ("broken input",), tmp_path / "bad", retries=2, log=tmp_path / "bad.log"),
        Job("c", _add, (1,), tmp_path / "c", after=("bad",)),
        Job("d", _add, (1,), tmp_path / "d", after=("c",)),
    ]
    seen: List[str] = []
    report = run_jobs(jobs, LocalExecutor(), lambda job, value: seen.append(job.key), "test jobs")
    assert report.done == {"a": 6, "b": 7} and seen == ["a", "b"]
    assert set(report.failed) == {"bad"} and report.skipped == {"c": "bad", "d": "c"}
    failure = report.failed["bad"]
    assert failure.attempts == 3 and "RuntimeError: broken input" in failure.error
    text = failures_markdown(report, "Failed")
    assert "## bad" in text and "after 3 attempt(s)" in text and str(tmp_path / "bad.log") in text
    assert "## c\n\nNot run: it needs `bad`, which failed." in text and "## d\n\nNot run: it needs `c`" in text
    with pytest.raises(ValueError, match="not in the list"):
        run_jobs([Job("x", _double, (1,), tmp_path, after=("y",))], LocalExecutor(), lambda j, v: None, "x")


def test_grid_plan_keys_streams_and_skips_finished_runs() -> None:
    runs = bench_grid.plan(["s1", "s2"], ["agrinerf-lite", "tensorf"], [0, 3], done={("s1", "tensorf@s3")})
    assert len(runs) == 7 and ("s1", "tensorf@s3") not in {(r.scene, r.key) for r in runs}
    assert runs[1].key == "agrinerf-lite@s3"
    method = bench_grid.seeded_method(bench_grid.METHODS["tensorf"], 3)
    assert method.train_args[-2:] == ("--machine.seed", "3") and method.dataparser_args == ("nerfstudio-data",)
    assert bench_grid.seeded_method(bench_grid.METHODS["tensorf"], 0) == bench_grid.METHODS["tensorf"]
    assert (
        bench_grid.run_resources("full", None, None).gpus == 1 and bench_grid.run_resources("quick", 2, None).gpus == 0
    )


HOLD_LOCK = """
import sys, time
from pathlib import Path
from agrinerf_ns.orchestrate.jobs import driver_lock
with driver_lock(Path(sys.argv[1])):
    print("held", flush=True)
    time.sleep(600)
"""


def test_a_second_driver_on_the_same_folder_stops_and_a_killed_holder_frees_it(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    with driver_lock(out):
        with pytest.raises(FolderInUse, match=f"{os.getpid()}"):  # names the holder
            with driver_lock(out):
                pass
        with driver_lock(tmp_path / "other"):  # another folder is another lock
            pass
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(FolderInUse, match=f"{holder.pid}"):
            bench_grid.run_grid([], PROFILE, BenchLayout(out), out / "results.csv", 0, LocalExecutor())
        assert not (out / "results.csv").exists(), "the second driver wrote nothing"
    finally:
        holder.kill()  # as SIGKILL ends a driver: no clean-up runs, the kernel drops its lock
        holder.wait()
    report = bench_grid.run_grid([], PROFILE, BenchLayout(out), out / "results.csv", 0, LocalExecutor())
    assert not report.done and (out / DRIVER_LOCK).exists()


def test_survey_and_bench_command_lines_and_bad_survey_folders(tmp_path: Path) -> None:
    import tyro

    from agrinerf_ns.lab.cli import BenchConfig
    from agrinerf_ns.survey.cli import SurveyArgs, SurveyInputError, list_captures

    args = tyro.cli(SurveyArgs, args=["--captures", "c", "--out", "o", "--ray", "auto", "--process.poses", "given",
                                      "--gpus-per-train", "1", "--train-args=--pipeline.model.final-resolution 64"])  # fmt: skip
    assert args.ray == "auto" and args.process.poses == "given" and args.gpus_per_train == 1.0
    assert args.train_args == "--pipeline.model.final-resolution 64"
    bench = tyro.cli(BenchConfig, args=["--ray", "local", "--run-seeds", "0", "1", "--cpus-per-run", "2"])
    assert bench.ray == "local" and bench.run_seeds == (0, 1) and bench.cpus_per_run == 2
    with pytest.raises(SurveyInputError, match="does not exist"):
        list_captures(tmp_path / "missing", tmp_path / "out")
    (tmp_path / "captures").mkdir()
    with pytest.raises(SurveyInputError, match="no capture folders"):
        list_captures(tmp_path / "captures", tmp_path / "out")
    (tmp_path / "captures" / "row-1").mkdir()
    with pytest.raises(SurveyInputError, match="inside the captures folder"):
        list_captures(tmp_path / "captures", tmp_path / "captures" / "survey")
    assert list_captures(tmp_path / "captures", tmp_path / "out") == ["row-1"]


def test_count_interval_is_the_view_jackknife_by_hand() -> None:
    """Two fruit, one seen in every view and one in the even views only: leaving out an interleaved group of views
    keeps both unless it holds all of the second's views."""
    import numpy as np

    from agrinerf_ns.count.cluster import ClusterConfig, Fruit
    from agrinerf_ns.count.lift import LiftedDetection
    from agrinerf_ns.count.render import RenderedView, RenderSet, WorldFrame
    from agrinerf_ns.survey.intervals import count_interval, jackknife_counts, mean_temperature

    views = 4
    detections = [LiftedDetection(v, np.array([0.0, 0.0, 1.0]), 0.08, 1.0, 20.0) for v in range(views)]
    detections += [LiftedDetection(v, np.array([1.0, 0.0, 1.0]), 0.08, 1.0, 24.0) for v in (0, 2)]
    blank = np.zeros((2, 2)), np.zeros((2, 2, 3))
    view = RenderedView("0", "train", "images/0.png", blank[1], blank[0], blank[0], blank[1], blank[1], 1.0)
    renders = RenderSet([view] * views, WorldFrame(np.eye(4)[:3], 1.0), None, None, None)
    cluster = ClusterConfig(min_views=2, min_view_fraction=0.0, merge_distance=0.2)
    # groups of 2: leaving out the even views (group 0) drops the second fruit
    assert jackknife_counts(detections, renders, cluster, 2) == [1, 2]
    low, high = count_interval(2, detections, renders, cluster, groups=2)
    half = 12.706205 * np.sqrt(0.5 * 0.5)  # t(0.975, 1 dof) * sqrt((g - 1) / g * sum of squares)
    assert (low, high) == pytest.approx((0.0, 2 + half), rel=1e-5), "the lower end is clipped at 0"
    assert all(np.isnan(count_interval(2, detections, renders, cluster, groups=1))), "one group: no interval"
    fruit = [Fruit(np.zeros(3), 0.08, 2, 2, t, 1.0) for t in (20.0, 22.0, None)]
    mean, half_t = mean_temperature(fruit)
    assert mean == 21.0 and half_t == pytest.approx(12.706205 * np.sqrt(2.0) / np.sqrt(2.0), rel=1e-5)


# --- on a local Ray ---------------------------------------------------------------------------------------------


def _ray_processes(temp_dir: Path) -> List[int]:
    """Processes whose command line names the Ray session folder ``temp_dir``."""
    pids = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            if str(temp_dir) in (proc / "cmdline").read_bytes().decode(errors="replace"):
                pids.append(int(proc.name))
        except OSError:
            continue
    return pids


@pytest.fixture(scope="module")
def local_ray() -> Iterator[str]:
    """A local Ray of 2 CPUs shared by this module's tests; yields its address. Stopped at the end, and no process
    of its session may be left."""
    ray = pytest.importorskip("ray")
    from agrinerf_ns.orchestrate.ray_executor import ray_init

    temp_dir = Path(tempfile.mkdtemp(prefix="ray-", dir="/tmp"))  # short: Ray's socket paths must fit 107 bytes
    ray_init("local", num_cpus=2, object_store_mb=100, temp_dir=temp_dir)
    try:
        yield ray.get_runtime_context().gcs_address
    finally:
        ray.shutdown()
        deadline = time.monotonic() + 30
        while _ray_processes(temp_dir) and time.monotonic() < deadline:
            time.sleep(0.5)
        left = _ray_processes(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)
        assert not left, f"Ray processes left behind: {left}"


def _children(pid: int) -> List[int]:
    kids: List[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            kids += [int(k) for k in task.read_text().split()]
        except OSError:
            continue
    return kids


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _kill_worker_once_training(folder: Path, killed: Dict[str, int], stop: threading.Event) -> None:
    """When a job of ``folder`` has started ``ns-train``, SIGKILL the worker process running it (not ns-train)."""
    while not stop.is_set():
        for attempt in attempts(folder):
            worker = attempt["pid"]
            trainers = [k for k in _children(worker) if b"ns-train" in Path(f"/proc/{k}/cmdline").read_bytes()]
            if trainers:
                time.sleep(3.0)  # well into ns-train's start-up
                killed.update(worker=worker, trainer=trainers[0])
                os.kill(worker, signal.SIGKILL)
                return
        time.sleep(0.2)


def _rows_per_run(csv_path: Path) -> Dict[str, List[str]]:
    steps: Dict[str, List[str]] = {}
    for row in results.read_rows(csv_path):
        steps.setdefault(row["method"], []).append(row["step"])
    return steps


@pytest.mark.slow
def test_a_killed_worker_is_retried_and_each_run_is_kept_once(local_ray: str, tmp_path: Path) -> None:
    from agrinerf_ns.orchestrate.ray_executor import RayExecutor

    layout = BenchLayout(tmp_path / "bench")
    runs = bench_grid.plan([SCENE], ["agrinerf-lite"], [0, 1], set())
    victim = experiment_folder(layout.runs, SCENE, "agrinerf-lite@s1")
    killed: Dict[str, int] = {}
    stop = threading.Event()
    killer = threading.Thread(target=_kill_worker_once_training, args=(victim, killed, stop), daemon=True)
    killer.start()
    executor = RayExecutor(local_ray)
    try:
        report = bench_grid.run_grid(runs, PROFILE, layout, layout.results_csv, 0, executor, Resources(cpus=1), 1)
    finally:
        stop.set()
        executor.close()
    assert killed, "the worker was not killed: the run finished before ns-train started?"
    assert not report.failed and not report.skipped
    assert len(attempts(victim)) == 2, "the killed run ran again"
    assert not _alive(killed["trainer"]), "the killed worker's ns-train is still running"
    assert _rows_per_run(layout.results_csv) == {"agrinerf-lite": ["13", "24"], "agrinerf-lite@s1": ["13", "24"]}
    assert not (layout.out / bench_grid.FAILURES_MD).exists()


DRIVER = """
import signal
import sys
from pathlib import Path
# as an interactive shell starts a command: Ctrl-C handled. A suite started in the background by a non-interactive
# shell (`pytest &`, `nohup`) runs with SIGINT ignored, and every process it starts inherits that; the masks the
# driver came with go to its log
print(*(line.strip() for line in open("/proc/self/status") if line.startswith(("SigBlk", "SigIgn"))), flush=True)
signal.pthread_sigmask(signal.SIG_UNBLOCK, {{signal.SIGINT}})
signal.signal(signal.SIGINT, signal.default_int_handler)
from agrinerf_ns.lab.layout import BenchLayout
from agrinerf_ns.lab.profiles import BenchProfile
from agrinerf_ns.lab import bench_grid
from agrinerf_ns.orchestrate.jobs import Resources
from agrinerf_ns.orchestrate.ray_executor import RayExecutor
profile = BenchProfile(**{profile})
layout = BenchLayout(Path(sys.argv[1]))
runs = bench_grid.plan([{scene!r}], ["agrinerf-lite"], [0, 1, 2], set())
executor = RayExecutor(sys.argv[2])
try:
    bench_grid.run_grid(runs, profile, layout, layout.results_csv, 0, executor, Resources(cpus=2), 1)
finally:
    executor.close()
"""
"""The interrupted driver: each run takes both of the local Ray's CPUs, so the runs finish one after another and the
interrupt lands while runs are still to do (two at a time, a poll could return them all at once)."""


@pytest.mark.slow
def test_an_interrupted_driver_resumes_without_redoing_finished_runs(local_ray: str, tmp_path: Path) -> None:
    from agrinerf_ns.orchestrate.ray_executor import RayExecutor

    layout = BenchLayout(tmp_path / "bench")
    fields = {"views": 8, "width": 64, "height": 48, "steps": PROFILE.steps, "evaluations": 2, "rays_per_batch": 128,
              "scenes": (SCENE,)}  # fmt: skip
    log = open(tmp_path / "driver.log", "w")
    driver = subprocess.Popen([sys.executable, "-c", DRIVER.format(profile=repr(fields), scene=SCENE),
                               str(layout.out), local_ray], stdout=log, stderr=subprocess.STDOUT)  # fmt: skip
    deadline = time.monotonic() + 900
    while not results.read_rows(layout.results_csv) and driver.poll() is None and time.monotonic() < deadline:
        time.sleep(0.5)
    assert driver.poll() is None, f"the driver stopped early: {(tmp_path / 'driver.log').read_text()[-2000:]}"
    first = {(r["scene"], r["method"]) for r in results.read_rows(layout.results_csv)}
    assert first, "no run finished before the interrupt (the machine too slow for the deadline?)"
    deadline = time.monotonic() + 60
    while driver.poll() is None and time.monotonic() < deadline:
        driver.send_signal(signal.SIGINT)  # Ctrl-C, pressed again while the driver still runs (a wait may hold it)
        try:
            driver.wait(timeout=2)
        except subprocess.TimeoutExpired:
            pass
    try:  # a driver still shutting down (Ray's disconnect under load) must end before the resume starts
        driver.wait(timeout=120)
    except subprocess.TimeoutExpired:
        driver.kill()
        driver.wait()
        pytest.fail(f"the driver kept running 3 minutes after Ctrl-C: {(tmp_path / 'driver.log').read_text()[-2000:]}")
    finally:
        log.close()
    assert driver.returncode is not None and driver.returncode != 0, (
        f"the driver was not interrupted: {(tmp_path / 'driver.log').read_text()[:300]}"
    )
    finished = {(r["scene"], r["method"]) for r in results.read_rows(layout.results_csv)}
    assert first <= finished and len(finished) < 3, "interrupted with runs still to do"
    records = {key: train_record(layout.runs, SCENE, key).stat().st_mtime for _, key in finished}

    runs = bench_grid.plan(
        [SCENE], ["agrinerf-lite"], [0, 1, 2], results.done_runs(results.read_rows(layout.results_csv))
    )
    assert {(r.scene, r.key) for r in runs}.isdisjoint(finished)
    executor = RayExecutor(local_ray)
    try:
        report = bench_grid.run_grid(runs, PROFILE, layout, layout.results_csv, 0, executor, Resources(cpus=1), 1)
    finally:
        executor.close()
    assert not report.failed
    assert _rows_per_run(layout.results_csv) == {k: ["13", "24"] for k in ("agrinerf-lite", "agrinerf-lite@s1",
                                                                            "agrinerf-lite@s2")}  # fmt: skip
    for key, mtime in records.items():
        assert len(attempts(experiment_folder(layout.runs, SCENE, key))) == 1, f"{key} ran again"
        assert train_record(layout.runs, SCENE, key).stat().st_mtime == mtime


@pytest.mark.slow
def test_a_survey_of_three_captures_on_ray_reports_the_broken_one(local_ray: str, tmp_path: Path) -> None:
    """Three synthetic captures in two lightings and one whose calibration is broken: the three are processed,
    trained and counted against their truth; the broken one is reported with its error. Run again, finished steps
    are not redone; without --ray the same steps run in this process."""
    from agrinerf_ns.process import ProcessConfig
    from agrinerf_ns.survey.cli import SurveyArgs, main
    from agrinerf_ns.synth import SynthConfig, generate_capture

    captures = tmp_path / "captures"
    for scene, lighting in (("orchard", "bright"), ("orchard", "dark"), ("garden", "bright")):
        generate_capture(SynthConfig.tiny(scene=scene, lighting=lighting), captures / f"{scene}-{lighting}")
    shutil.copytree(captures / "garden-bright", captures / "broken")
    (captures / "broken" / "calib.yaml").write_text("cam0: [not, a, camera\n")
    args = SurveyArgs(captures=captures, out=tmp_path / "survey", steps=30, rays_per_batch=256, ray=local_ray,
                      process=ProcessConfig(poses="given", show_progress=False), retries=0)  # fmt: skip
    rows = {r["capture"]: r for r in main(args)}
    assert [rows[c]["status"] for c in sorted(rows)] == ["failed at process", "done", "done", "done"]
    assert "calib.yaml" in rows["broken"]["error"]
    for name in ("garden-bright", "orchard-bright", "orchard-dark"):
        row = rows[name]
        assert row["truth_visible"] > 0 and row["fruit"] >= 0 and row["train_s"] > 0
        assert row["count_error"] == pytest.approx((row["fruit"] - row["truth_visible"]) / row["truth_visible"])
        count = json.loads((tmp_path / "survey" / "captures" / name / "count" / "count.json").read_text())
        assert count["fruit"] == row["fruit"] and count["score"]["visible"] == row["truth_visible"]
    table = (tmp_path / "survey" / "survey.md").read_text()
    assert "| orchard-dark | done |" in table and "broken: " in table and "calib.yaml" in table
    assert "calib.yaml" in (tmp_path / "survey" / "failures.md").read_text()

    records = {p: p.stat().st_mtime for p in (tmp_path / "survey" / "captures").glob("*/*.json")}
    again = {r["capture"]: r for r in main(SurveyArgs(**{**vars(args), "ray": None}))}
    assert again["broken"]["status"] == "failed at process" and again["orchard-dark"] == rows["orchard-dark"]
    assert {p: p.stat().st_mtime for p in records} == records, "finished steps were redone"
