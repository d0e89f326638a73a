"""Two ways of counting compared capture by capture: the paired difference of each measure, with its bootstrap 95%
interval over the captures.

``python benchmarks/count_paired.py --a LABEL=COUNTS_CSV[:ROW_LABEL] --b LABEL=COUNTS_CSV[:ROW_LABEL] --out FILE.md``
reads two ``counts.csv`` tables (``benchmarks/count_fruit_table.py``, ``agrinerf-bench --profile count``, or any
with the columns ``scene``, ``lighting``, ``seed``, ``label`` and the measures), keeps in each the rows of
``ROW_LABEL`` (every row when it is left out), pairs the rows of one capture (scene, lighting, seed) and writes, per
lighting and for all lightings together, the captures paired, each side's mean and the mean of b - a with its
interval (resampling the captures). A capture only one table holds is listed, not paired.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import tyro

from agrinerf_ns.lab.count_tables import bootstrap_mean

Capture = Tuple[str, str, str]
ORDER = ("bright", "shadowed", "dusk", "dark")


@dataclass
class PairedArgs:
    a: str
    """LABEL=COUNTS_CSV[:ROW_LABEL]: the first way (the reference)."""
    b: str
    """LABEL=COUNTS_CSV[:ROW_LABEL]: the second way (its difference from the first is given)."""
    out: Path
    """The markdown file written."""
    measures: Tuple[str, ...] = ("f1", "count_error", "f1_well_seen")
    """Columns compared (those both tables hold)."""


def read_side(spec: str) -> Tuple[str, Dict[Capture, Dict[str, str]]]:
    """``LABEL=CSV[:ROW_LABEL]`` -> the label and its rows by capture; ValueError naming the file on a bad table."""
    label, _, rest = spec.partition("=")
    path, _, row_label = rest.partition(":")
    if not label or not path:
        raise ValueError(f"{spec}: give LABEL=COUNTS_CSV[:ROW_LABEL]")
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    rows = [r for r in rows if not row_label or r.get("label") == row_label]
    if not rows:
        raise ValueError(f"{path}: no rows{f' labelled {row_label!r}' if row_label else ''}")
    by_capture: Dict[Capture, Dict[str, str]] = {}
    for row in rows:
        key = (row["scene"], row["lighting"], row["seed"])
        if key in by_capture:
            raise ValueError(f"{path}: two rows of {key}; name one ROW_LABEL")
        by_capture[key] = row
    return label, by_capture


def paired_rows(
    a: Dict[Capture, Dict[str, str]], b: Dict[Capture, Dict[str, str]], measures: Sequence[str]
) -> List[List[str]]:
    """Per lighting, then all together: captures, each side's mean and b - a [interval] of every measure."""
    shared = sorted(set(a) & set(b), key=lambda k: (ORDER.index(k[1]) if k[1] in ORDER else 9, k[0], int(k[2])))
    groups = [(light, [k for k in shared if k[1] == light]) for light in dict.fromkeys(k[1] for k in shared)]
    groups.append(("all", shared))
    table = []
    for light, keys in groups:
        cells = [light, str(len(keys))]
        for measure in measures:
            pairs = [(float(a[k][measure]), float(b[k][measure])) for k in keys]
            pairs = [(x, y) for x, y in pairs if math.isfinite(x) and math.isfinite(y)]
            diff = bootstrap_mean([y - x for x, y in pairs])
            mean_a = sum(x for x, _ in pairs) / max(len(pairs), 1)
            mean_b = sum(y for _, y in pairs) / max(len(pairs), 1)
            cells += [f"{mean_a:.2f}", f"{mean_b:.2f}", f"{diff.value:+.2f} [{diff.low:+.2f}, {diff.high:+.2f}]"]
        table.append(cells)
    return table


def main(args: PairedArgs) -> str:
    label_a, a = read_side(args.a)
    label_b, b = read_side(args.b)
    header = ["lighting", "captures"]
    for measure in args.measures:
        header += [f"{measure}: {label_a}", f"{measure}: {label_b}", f"{measure}: b - a [95%]"]
    lines = [f"# {label_b} against {label_a}, capture by capture", "",
             f"a: `{args.a}`; b: `{args.b}`. Mean of b - a over the captures both hold, bootstrap 95% interval "
             "over the captures.", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]  # fmt: skip
    lines += ["| " + " | ".join(row) + " |" for row in paired_rows(a, b, args.measures)]
    alone = sorted(set(a) ^ set(b))
    if alone:
        lines += ["", "Held by one table only (not paired): " + ", ".join(":".join(k) for k in alone) + "."]
    text = "\n".join(lines) + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)
    return text


if __name__ == "__main__":
    print(main(tyro.cli(PairedArgs)))
