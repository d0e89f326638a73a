"""Peak memory of ``agrinerf-process`` on a capture whose event file holds 5e7 events.

    python benchmarks/bench_events_memory.py --work /tmp/bench_events [--num-events 50000000]

Builds a raw capture (the tiny synthetic scene from ``agrinerf-synth``, its events.h5 replaced by ``num_events``
uniformly spread, time-sorted events over the RGB time span, written in chunks), then runs
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


def write_events(path: Path, n: int, t0_us: int, t1_us: int, w: int, h: int, seed: int, chunk: int = 5_000_000):
    rng = np.random.default_rng(seed)
    edges = np.linspace(t0_us, t1_us, n // chunk + 2).astype(np.int64)
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        ds = {k: g.create_dataset(k, shape=(n,), dtype=dt, chunks=(min(n, 1 << 20),))
              for k, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.uint8))}
        for i, s in enumerate(range(0, n, chunk)):
            m = min(chunk, n - s)
            ds["t"][s : s + m] = np.sort(rng.integers(edges[i], edges[i + 1], m))
            ds["x"][s : s + m] = rng.integers(0, w, m, dtype=np.uint16)
            ds["y"][s : s + m] = rng.integers(0, h, m, dtype=np.uint16)
            ds["p"][s : s + m] = rng.integers(0, 2, m, dtype=np.uint8)


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
    write_events(raw / "events" / "events.h5", args.num_events, int((times[0] - 0.1) * 1e6), int(times[-1] * 1e6),
                 cam.width, cam.height, args.seed)
    write_s = time.perf_counter() - t0
    cmd = ["/usr/bin/time", "-v", "agrinerf-process", "--raw", str(raw), "--out", str(args.work / "ds"),
           "--poses", "given", "--no-show-progress"]
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
        "file_mb": round((raw / "events" / "events.h5").stat().st_size / 2**20, 1),
        "peak_rss_mib": round(peak_kb / 1024, 1),
        "limit_mib": args.limit_gib * 1024,
        "process_wall_s": round(wall, 1),
        "write_events_s": round(write_s, 1),
        "chunk_size": meta["chunk_size"],
    }
    print(json.dumps(result, indent=2))
    if peak_kb / 2**20 >= args.limit_gib:
        raise SystemExit(f"peak {peak_kb / 1024:.0f} MiB is over {args.limit_gib} GiB")
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
