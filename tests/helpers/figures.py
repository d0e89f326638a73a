"""Quoted figures against the results files they come from (issue #51).

``results/figures.json`` lists every measured figure that README.md and docs/results.md quote: the text as quoted,
written as a format template (``"{0:+.2f} dB"``), and the values that fill it, each picked from a committed CSV or JSON
file under results/. Its ``sources`` name, for each results folder, the command that wrote the files and the file that
records the commit, machine and date. :func:`check` renders every entry and reports the texts missing from their doc;
:func:`unregistered` reports numbers in the docs that look measured and that no entry or allowlisted phrase covers.
"""

from __future__ import annotations

import csv
import json
import re
import statistics
from pathlib import Path
from typing import Any, Dict, List

ROOT = Path(__file__).resolve().parents[2]
REGISTRY = ROOT / "results" / "figures.json"

# A number with a unit that marks it as measured: dB, %, seconds, minutes, C, cm, GiB, a ratio (0.2x, not 96x72),
# or a bare decimal with two or more places (SSIM, F1, mAP shares).
MEASURED = re.compile(
    r"(?<![\w.])[+-]?\d+(?:\.\d+)?(?:"
    r"\s?(?:dB|%|s\b|min\b|C\b|cm\b|GiB\b)"
    r"|x(?![\d^])"
    r")"
    r"|(?<![\w.])[+-]?\d+\.\d{2,}(?![\d.])"
)
CODE = re.compile(r"```.*?```|`[^`\n]*`|\]\([^)]*\)|<!--.*?-->", re.S)
COMMIT = re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
MACHINE = re.compile(r"Xeon|EPYC|Ryzen|Core\(TM\)|NVIDIA|H100|H200", re.I)


def load(path: Path = REGISTRY) -> Dict[str, Any]:
    """The registry."""
    return json.loads(path.read_text())


def _rows(path: Path) -> List[Dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _match(rows: List[Dict[str, str]], where: Dict[str, Any]) -> List[Dict[str, str]]:
    return [r for r in rows if all(r.get(k) == str(v) for k, v in where.items())]


def _one(rows: List[Dict[str, str]], where: Dict[str, Any], last: bool, what: str) -> Dict[str, str]:
    """The row that ``where`` picks: the only match, or with ``last`` the match at the highest step."""
    found = _match(rows, where)
    if not found:
        raise LookupError(f"{what}: no row with {where}")
    if last:
        return max(found, key=lambda r: int(r["step"]))
    if len(found) > 1:
        raise LookupError(f"{what}: {len(found)} rows with {where}")
    return found[0]


def _per_view(row: Dict[str, str]) -> List[float]:
    return [float(v) for v in row["psnr_clean_per_view"].split(";") if v]


def value(sel: Dict[str, Any], root: Path = ROOT) -> float:
    """One figure from a selector, times its ``"scale"`` (default 1), divided by the figure of its ``"over"``
    selector, less that of its ``"minus"`` selector."""
    over = value(sel["over"], root) if "over" in sel else 1.0
    minus = value(sel["minus"], root) if "minus" in sel else 0.0
    return _raw(sel, root) * sel.get("scale", 1) / over - minus


def _raw(sel: Dict[str, Any], root: Path = ROOT) -> float:
    """A selector's figure:

    - ``{"csv", "where", "column"}``: a cell (``"last": true``: the row at the highest step; ``"agg"``: min, max,
      mean or median over every matching row).
    - ``{"json", "key"}``: a value at a dotted key path (list indices as numbers).
    - ``{"paired", "scene", "method", "base"}``: the mean per-view PSNR difference of two runs (``"part": "half"``:
      its 95% half-width, with ``"spread"`` also the between-stream spread, as the benchmark's report computes it).
    - ``{"ratio", "run", "base"}``: the median over rounds of a step-time ratio (``bench_step_interleaved`` CSVs).
    """
    if "csv" in sel:
        rows = _rows(root / sel["csv"])
        if "agg" in sel:
            cells = [float(r[sel["column"]]) for r in _match(rows, sel["where"])]
            if not cells:
                raise LookupError(f"{sel['csv']}: no row with {sel['where']}")
            return float(
                {"min": min, "max": max, "mean": statistics.mean, "median": statistics.median}[sel["agg"]](cells)
            )
        return float(_one(rows, sel["where"], sel.get("last", False), sel["csv"])[sel["column"]])
    if "json" in sel:
        data: Any = json.loads((root / sel["json"]).read_text())
        for part in str(sel["key"]).split("."):
            data = data[int(part)] if isinstance(data, list) else data[part]
        return float(data)
    if "paired" in sel:
        from agrinerf_ns.lab import results

        rows = _rows(root / sel["paired"])
        mine = _one(rows, {"scene": sel["scene"], "method": sel["method"]}, True, sel["paired"])
        base = _one(rows, {"scene": sel["scene"], "method": sel["base"]}, True, sel["paired"])
        mean, half = results.paired_difference(_per_view(mine), _per_view(base))
        if sel.get("part", "mean") == "mean":
            return mean
        if "spread" in sel:
            spread = sel["spread"]
            sd, dof = results.difference_spread(rows, spread["methods"], sel["base"], spread["seeds"])
            half = results.difference_interval(half, sd, dof, runs_factor=1.0)
        return half
    if "ratio" in sel:
        rounds: Dict[str, Dict[str, float]] = {}
        for r in _rows(root / sel["ratio"]):
            rounds.setdefault(r["round"], {})[r["run"]] = float(r["seconds"])
        return statistics.median(t[sel["run"]] / t[sel["base"]] for t in rounds.values() if sel["run"] in t)
    raise ValueError(f"unknown selector {sel}")


def render(entry: Dict[str, Any], root: Path = ROOT) -> str:
    """An entry's text with its values filled in."""
    return str(entry["text"]).format(*(value(sel, root) for sel in entry["values"]))


def check(registry: Dict[str, Any], root: Path = ROOT) -> List[str]:
    """Problems: every entry whose rendered text is missing from its doc, or whose source is not recorded."""
    problems = []
    docs: Dict[str, str] = {}
    for entry in registry["figures"]:
        source = registry["sources"].get(entry["source"])
        if source is None:
            problems.append(f"{entry['text']!r}: unknown source {entry['source']!r}")
            continue
        text = render(entry, root)
        doc = docs.setdefault(entry["doc"], (root / entry["doc"]).read_text())
        if text not in doc:
            problems.append(f"{entry['doc']}: {text!r} (from {entry['source']}) is not quoted")
    return problems


def provenance(name: str, source: Dict[str, Any], root: Path = ROOT) -> List[str]:
    """Problems with a source's record: its file must name the command's script, a commit, a machine and a date,
    and sit in the folder of the files the figures read."""
    record = root / source["record"]
    if not record.is_file():
        return [f"{name}: no record {source['record']}"]
    text = record.read_text()
    script = next(w for w in source["command"].split() if "/" in w or w.startswith("agrinerf-"))
    missing = [
        what
        for what, ok in (
            (f"the command's {script}", script in text),
            ("a commit", COMMIT.search(text)),
            ("a machine", MACHINE.search(text)),
            ("a date", DATE.search(text)),
        )
        if not ok
    ]
    return [f"{name}: {source['record']} does not record {', '.join(missing)}"] if missing else []


def unregistered(registry: Dict[str, Any], docs: List[str], root: Path = ROOT) -> List[str]:
    """Measured-looking numbers in ``docs`` outside every rendered entry text and allowlisted phrase (code, link
    targets and comments are skipped)."""
    covered: Dict[str, List[str]] = {doc: list(registry["allow"].get(doc, [])) for doc in docs}
    for entry in registry["figures"]:
        if entry["doc"] in covered:
            covered[entry["doc"]].append(render(entry, root))
    found = []
    for doc in docs:
        text = (root / doc).read_text()
        for phrase in sorted(covered[doc], key=len, reverse=True):
            text = text.replace(phrase, " ")
        text = CODE.sub(" ", text)
        found += [
            f"{doc}: {m.group(0).strip()!r} in ...{text[max(0, m.start() - 40) : m.end() + 20]!r}..."
            for m in MEASURED.finditer(text)
        ]
    return found
