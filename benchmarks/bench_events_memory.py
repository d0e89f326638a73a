"""Peak memory of ``agrinerf-process`` on a capture whose event file holds 5e7 events.

    python benchmarks/bench_events_memory.py --work /tmp/bench_events [--num-events 50000000]
    python benchmarks/bench_events_memory.py --format raw --num-events 100000000 --out results/events-memory/raw.md

Builds a raw capture (the tiny synthetic scene from ``agrinerf-synth``, its events.h5 replaced by ``num_events``
uniformly spread, time-sorted events over the RGB time span, written in chunks; ``--format raw``: a Prophesee
EVT 3.0 ``events.raw`` instead, written with ``event_codecs.Evt3Encoder``), then runs
``/usr/bin/time -v agrinerf-process --poses given`` on it and reports the child's maximum resident set size.
A full in-memory load of x, y, t, p alone would be 13 bytes x 5e7 = 650 MB, plus the int64 index arrays a naive
accumulation builds (2 x 400 MB); streaming keeps the peak at O(chunk) instead.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import tyro


@dataclass
class Args:
    work: Path = Path("/tmp/agrinerf_bench_events")
    """Scratch folder (raw capture, dataset, log); replaced."""
    num_events: int = 50_000_000
    """Events in the file."""
    limit_gib: float = 2.0
    """Fail (exit 1) above this peak."""
    seed: int = 0
    format: str = "h5"
    """Event file: h5 (events.h5) or raw (EVT 3.0 events.raw)."""
    out: Path | None = None
    """Also write the result as a Markdown table here (with the command and the machine)."""


def write_events(path: Path, n: int, t0_us: int, t1_us: int, w: int, h: int, seed: int, chunk: int = 5_000_000):
    rng = np.random.default_rng(seed)
    edges = np.linspace(t0_us, t1_us, n // chunk + 2).astype(np.int64)
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        ds = {
            k: g.create_dataset(k, shape=(n,), dtype=dt, chunks=(min(n, 1 << 20),))
            for k, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.uint8))
        }
        for i, s in enumerate(range(0, n, chunk)):
            m = min(chunk, n - s)
            ds["t"][s : s + m] = np.sort(rng.integers(edges[i], edges[i + 1], m))
            ds["x"][s : s + m] = rng.integers(0, w, m, dtype=np.uint16)
            ds["y"][s : s + m] = rng.integers(0, h, m, dtype=np.uint16)
            ds["p"][s : s + m] = rng.integers(0, 2, m, dtype=np.uint8)


def write_events_raw(path: Path, n: int, t0_us: int, t1_us: int, w: int, h: int, seed: int, chunk: int = 5_000_000):
    """The same random events as :func:`write_events`, as an EVT 3.0 ``.raw`` file."""
    from agrinerf_ns.process.event_codecs import Evt3Encoder, evt3_header

    rng = np.random.default_rng(seed)
    edges = np.linspace(t0_us, t1_us, n // chunk + 2).astype(np.int64)
    enc = Evt3Encoder()
    with open(path, "wb") as fh:
        fh.write(evt3_header(w, h))
        for i, s in enumerate(range(0, n, chunk)):
            m = min(chunk, n - s)
            t = np.sort(rng.integers(edges[i], edges[i + 1], m))
            x = rng.integers(0, w, m, dtype=np.uint16)
            y = rng.integers(0, h, m, dtype=np.uint16)
            p = rng.integers(0, 2, m, dtype=np.uint8)
            fh.write(enc.encode(x, y, t, p).tobytes())


def main(args: Args) -> dict:
    from agrinerf_ns.process.readers import read_calibration, read_timestamps
    from agrinerf_ns.synth import SynthConfig, generate_capture

    if args.work.exists():
        shutil.rmtree(args.work)
    raw = args.work / "raw"
    generate_capture(SynthConfig.tiny(), raw)
    cam = read_calibration(raw / "calib.yaml").event
    times = read_timestamps(raw / "rgb").times
    (raw / "events" / "events.h5").unlink()
    t0 = time.perf_counter()
    writer = {"h5": write_events, "raw": write_events_raw}[args.format]
    event_file = raw / "events" / f"events.{args.format}"
    writer(
        event_file, args.num_events, int((times[0] - 0.1) * 1e6), int(times[-1] * 1e6), cam.width, cam.height, args.seed
    )
    write_s = time.perf_counter() - t0
    cmd = [
        "/usr/bin/time",
        "-v",
        "agrinerf-process",
        "--raw",
        str(raw),
        "--out",
        str(args.work / "ds"),
        "--poses",
        "given",
        "--no-show-progress",
    ]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(proc.stderr[-3000:])
    peak_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", proc.stderr).group(1))
    meta = json.loads((args.work / "ds" / "transforms.json").read_text())["agrinerf"]["events"]
    result = {
        "num_events": args.num_events,
        "events_in_windows": meta["events_in_windows"],
        "format": args.format,
        "file_mb": round(event_file.stat().st_size / 2**20, 1),
        "peak_rss_mib": round(peak_kb / 1024, 1),
        "limit_mib": args.limit_gib * 1024,
        "process_wall_s": round(wall, 1),
        "write_events_s": round(write_s, 1),
        "chunk_size": meta["chunk_size"],
    }
    print(json.dumps(result, indent=2))
    if args.out is not None:
        write_table(args, result)
    if peak_kb / 2**20 >= args.limit_gib:
        raise SystemExit(f"peak {peak_kb / 1024:.0f} MiB is over {args.limit_gib} GiB")
    return result


def write_table(args: Args, result: dict) -> None:
    import platform
    import sys

    cpu = next(
        (
            ln.split(":", 1)[1].strip()
            for ln in Path("/proc/cpuinfo").read_text().splitlines()
            if ln.startswith("model name")
        ),
        platform.processor(),
    )
    rows = "\n".join(f"| {k} | {v} |" for k, v in result.items())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        f"# agrinerf-process peak memory, {args.num_events:.0e} events ({args.format})\n\n"
        f"Command: `python benchmarks/bench_events_memory.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: {cpu}, {len(__import__('os').sched_getaffinity(0))} cores; peak RSS of the agrinerf-process "
        f"process (`/usr/bin/time -v`).\n\n| quantity | value |\n|---|---|\n{rows}\n"
    )


if __name__ == "__main__":
    main(tyro.cli(Args))
