"""Chunked writer of a raw capture's ``events/events.h5`` (events/x, y, t, p and triggers/t, p, id)."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import numpy as np


class EventH5Writer:
    """Writes events (and trigger events) to ``folder/name`` in chunks (the raw capture's event layout,
    docs/formats.md); the file is created on the first write."""

    def __init__(self, folder: Path, chunk: int, name: str = "events.h5") -> None:
        self.folder, self.chunk, self.name, self.h5 = folder, chunk, name, None
        self.buf: Dict[str, List[np.ndarray]] = {k: [] for k in "xytp"}
        self.trig: Dict[str, List[np.ndarray]] = {k: [] for k in ("t", "p", "id")}
        self.n = 0

    def add(self, x, y, t, p) -> None:
        for k, a in zip("xytp", (x, y, t, p), strict=True):
            self.buf[k].append(a)
        self.n += len(t)
        if sum(len(a) for a in self.buf["t"]) >= self.chunk:
            self.flush()

    def add_triggers(self, t, p, ids) -> None:
        for k, a in zip(("t", "p", "id"), (t, p, ids), strict=True):
            self.trig[k].append(a)

    def _file(self):
        import h5py

        if self.h5 is None:
            self.folder.mkdir(exist_ok=True)
            self.h5 = h5py.File(self.folder / self.name, "w")
            g = self.h5.create_group("events")
            for k, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.uint8)):
                g.create_dataset(k, shape=(0,), maxshape=(None,), dtype=dt, chunks=(1 << 16,))
        return self.h5

    def flush(self) -> None:
        if not self.buf["t"]:
            return
        g = self._file()["events"]
        n0 = g["t"].shape[0]
        for k in "xytp":
            arr = np.concatenate(self.buf[k])
            g[k].resize((n0 + arr.shape[0],))
            g[k][n0:] = arr
            self.buf[k].clear()

    def close(self, offset_us: int, attrs: Dict) -> None:
        """Write what is buffered, shift every time by ``offset_us`` (chunk by chunk), write the triggers."""
        self.flush()
        if self.h5 is None and not self.trig["t"]:
            return
        f = self._file()
        g = f["events"]
        if offset_us:
            step = 1 << 22
            for s in range(0, g["t"].shape[0], step):
                g["t"][s : s + step] = g["t"][s : s + step] + offset_us
        if self.trig["t"]:
            tg = f.create_group("triggers")
            tg["t"] = np.concatenate(self.trig["t"]).astype(np.int64) + offset_us
            tg["p"] = np.concatenate(self.trig["p"]).astype(np.uint8)
            tg["id"] = np.concatenate(self.trig["id"]).astype(np.uint8)
        for k, v in attrs.items():
            f.attrs[k] = v
        f.close()
        self.h5 = None
