"""Quoted figures against the results files they come from (issues #51, #61).

``results/figures.json`` holds every measured figure that README.md, docs/*.md and results/*/README.md quote:

- ``figures``: a text as quoted, written as a format template (``"{0:+.2f} dB"``), and the values that fill it, each
  picked from a committed CSV or JSON file (:func:`value`). Its ``source`` names the command and the record (the file
  with the commit, machine and date); every file the values read lies in that record's folder, or in the folder of
  the record a selector names with its own ``"source"``.
- ``quoted``: per doc, per source file (``path``, or ``path#column`` for one column of a CSV), the numbers as the
  doc writes them; each must be a number of that file (rounded to the quoted places, or a share times 100 for a
  percent) and appear in the doc. This pins the file, not the cell: a short number may occur in a file by chance,
  so a figure that must equal one cell belongs in ``figures``.
- ``settings``: per doc, numbers that read as results but are not (a size, a step count, a threshold, a seed), under
  the reason why.
- ``unchecked``: per doc, measured numbers that no committed data file holds, under the reason why.

Each registration covers one occurrence of its number in its doc, so a figure added anywhere needs its own.
:func:`figures_in` finds the numbers that read as results; :func:`unregistered` reports those nothing covers.
"""

from __future__ import annotations

import csv
import json
import re
import statistics
from collections import Counter
from functools import lru_cache
from pathlib import Path
from typing import Any, Dict, Iterable, List, Set, Tuple

ROOT = Path(__file__).resolve().parents[2]
REGISTRY = ROOT / "results" / "figures.json"

UNITS = r"(?:dB|%|x|s|ms|min|h|°C|C|K|cm|mm|m|px|GiB|MiB|GB|MB|kB)"
METRIC = r"(?:PSNR|SSIM|LPIPS|F1|mAP\d*(?:-\d+)?|AP\d*|IoU|RMSE|MAE|[Rr]ecall|[Pp]recision)"
NUM = r"\d+(?:\.\d+)?"
NOT_FIGURES = re.compile(
    r"\]\([^)]*\)|<!--.*?-->|https?://\S+"  # link targets, comments, addresses
    r"|\b\d{4}-\d\d-\d\d\b|\b\d\d:\d\d(?::\d\d)?\b"  # dates, times of day
    r"|\b\d+(?:\.\d+){2,}\b"  # versions
    r"|\b\d+(?:x\d+)+\b|\b\d+\^\d+\b"  # image sizes (96x72), grids (128^3)
    r"|(?<![\w-])--[\w.-]+[ =][^\s`|]+",  # a command-line option's value: a setting
    re.S,
)
"""Text that holds no figure: blanked before the numbers are read."""
TOKEN = re.compile(r"(?<![\w.@=/#\\^])(?<![A-Za-z_]-)(" + NUM + r")(?![\d^]|\.\d)(?P<tail>[A-Za-z_°]*)")
"""A number standing on its own (not in a name such as ``mAP50``, ``s100`` or ``lite@1000``), maybe with a unit."""
UNIT_AFTER = re.compile(r"(?:\s?[-–/]\s?[+\-−]?" + NUM + r")*\s?" + UNITS + r"(?![A-Za-z])")
METRIC_BEFORE = re.compile(METRIC + r"(?:[^\w\n|]{0,3}|\s(?:of|at|is|=)\s)[+\-−]?$")
TABLE_RULE = re.compile(r"\s*\|[\s:|-]*$")
DATA = (".csv", ".json", ".jsonl", ".md", ".txt", ".tsv")
"""Files a figure may be read from."""

COMMIT = re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b")
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
MACHINE = re.compile(r"Xeon|EPYC|Ryzen|Core\(TM\)|NVIDIA|H100|H200", re.I)


def load(path: Path = REGISTRY) -> Dict[str, Any]:
    """The registry."""
    return json.loads(path.read_text())


def docs(root: Path = ROOT) -> List[str]:
    """The docs whose figures are checked: README.md, docs/*.md and results/*/README.md."""
    found = [root / "README.md", *sorted((root / "docs").glob("*.md")), *sorted((root / "results").glob("*/README.md"))]
    return [p.relative_to(root).as_posix() for p in found]


# --- which numbers read as results ---------------------------------------------------------------------------------


def figures_in(text: str) -> List[Tuple[str, int]]:
    """The numbers of a Markdown text that read as results, each as written (no sign) with its offset: every number
    in a table cell, every decimal, every number with a unit (dB, %, x, s, C, cm, ...) or after a metric's name (PSNR,
    SSIM, F1, mAP, IoU, ...), backticks and code blocks included. Dates, times of day, versions, image sizes, grids,
    link targets and comments are not read."""
    text = NOT_FIGURES.sub(lambda m: re.sub(r"\S", " ", m.group(0)), text)
    found = []
    start = 0
    for line in text.splitlines(keepends=True):
        table = line.lstrip().startswith("|") and not TABLE_RULE.match(line)
        for m in TOKEN.finditer(line):
            if m.group("tail") and not re.fullmatch(UNITS, m.group("tail")):
                continue  # 3D, 1st, 64th: a word, not a figure
            if re.search(r"[A-Za-z]\d+-$", line[: m.start()]):
                continue  # the 95 of mAP50-95
            num = m.group(1)
            unit = UNIT_AFTER.match(line, m.end(1)) is not None
            metric = METRIC_BEFORE.search(line[max(0, m.start() - 16) : m.start()]) is not None
            if "." in num or table or unit or metric:
                found.append((num, start + m.start(1)))
        start += len(line)
    return found


# --- numbers of a data file ----------------------------------------------------------------------------------------


@lru_cache(maxsize=None)
def _numbers(source: Path, column: str = "") -> Tuple[float, ...]:
    """A data file's numbers, or a CSV column's; of a CSV only the cells that are one number."""
    if source.suffix == ".csv":
        cells = [v for row in _rows(source) for k, v in row.items() if k == column or not column]
        text = " ".join(
            c for c in cells if isinstance(c, str) and re.fullmatch(r"\s*[-+]?[\d.]+(?:[eE][-+]?\d+)?\s*", c)
        )
    else:
        text = source.read_text(errors="replace")
    return tuple(float(n) for n in re.findall(r"(?<![\w.])\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", text))


@lru_cache(maxsize=None)
def _written(source: Path, column: str, places: int) -> Set[str]:
    """The numbers (absolute values) written with ``places`` decimals, and times 100 (a share as a percent)."""
    out = set()
    for n in _numbers(source, column):
        for v in (n, n * 100):
            out.update(f"{v * (1 + e):.{places}f}" for e in (-1e-9, 0.0, 1e-9))  # a tie (0.745) rounds either way
    return out


def holds(source: Path, number: str, column: str = "") -> bool:
    """Whether a data file (or one column of a CSV) holds ``number`` as quoted: one of its numbers rounded to the
    quoted places, or that number times 100 (a share quoted as a percent)."""
    places = len(number.split(".")[1]) if "." in number else 0
    return f"{float(number):.{places}f}" in _written(source, column, places)


# --- registered figures --------------------------------------------------------------------------------------------


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


def files_of(sel: Dict[str, Any], source: str = "") -> List[Tuple[str, str]]:
    """Every file a selector reads, its ``over`` and ``minus`` selectors' included, each with the source it is
    recorded by: the selector's own ``"source"``, else ``source`` (the entry's)."""
    source = sel.get("source", source)
    files = [(next(sel[k] for k in ("csv", "json", "paired", "ratio") if k in sel), source)]
    for part in ("over", "minus"):
        if part in sel:
            files += files_of(sel[part], source)
    return files


def outside(entry: Dict[str, Any], sources: Dict[str, Any], root: Path = ROOT) -> List[str]:
    """The files an entry reads outside the folder of the record that registers them (a top-level record's folder
    is its own, not results/)."""
    found = []
    for sel in entry["values"]:
        for path, name in files_of(sel, entry["source"]):
            record = sources.get(name, {}).get("record")
            if (
                record is None
                or not path.startswith("results/")
                or not (root / path).is_relative_to((root / record).parent)
            ):
                found.append(path)
    return found


def value(sel: Dict[str, Any], root: Path = ROOT) -> float:
    """One figure from a selector, times its ``"scale"`` (default 1), divided by the figure of its ``"over"``
    selector, less that of its ``"minus"`` selector (a selector's ``"source"`` names the record of a file outside
    the entry's record folder)."""
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
    """Problems: every entry whose rendered text is missing from its doc, whose source is not recorded, or that
    reads a file outside its record's folder."""
    problems = []
    texts: Dict[str, str] = {}
    for entry in registry["figures"]:
        source = registry["sources"].get(entry["source"])
        if source is None:
            problems.append(f"{entry['text']!r}: unknown source {entry['source']!r}")
            continue
        stray = outside(entry, registry["sources"], root)
        if stray:
            problems.append(f"{entry['text']!r}: reads {stray}, outside its record's folder")
            continue
        text = render(entry, root)
        doc = texts.setdefault(entry["doc"], (root / entry["doc"]).read_text())
        if text not in doc:
            problems.append(f"{entry['doc']}: {text!r} (from {entry['source']}) is not quoted")
    return problems


def _quoted(doc: str, registry: Dict[str, Any], root: Path) -> Counter:
    """The numbers a doc quotes (with their counts) outside every entry text and allowlisted phrase."""
    text = _uncovered_text(doc, registry, root)
    return Counter(n for n, _ in figures_in(text))


def check_quoted(registry: Dict[str, Any], root: Path = ROOT) -> List[str]:
    """Problems with ``quoted``, ``settings``, ``unchecked`` and ``allow``: a number its named file does not hold,
    one registered more often than its doc quotes it, or an allowed phrase its doc no longer has."""
    problems = []
    for doc, by_file in registry["quoted"].items():
        for name, numbers in by_file.items():
            path, _, column = name.partition("#")
            if Path(path).suffix not in DATA or not (root / path).is_file() or (column and not path.endswith(".csv")):
                problems.append(f"{doc}: source {name} is not a committed data file (or a CSV's column)")
                continue
            if column and column not in _rows(root / path)[0]:
                problems.append(f"{doc}: {path} has no column {column}")
                continue
            problems += [f"{doc}: {n} is not in {name}" for n in set(numbers) if not holds(root / path, n, column)]
    for doc, phrases in registry["allow"].items():
        text = (root / doc).read_text()
        problems += [f"{doc}: allowed phrase {p!r} is not quoted" for p in phrases if p not in text]
    for doc in {d for kind in ("quoted", "settings", "unchecked") for d in registry[kind]}:
        quoted = _quoted(doc, registry, root)
        for number, count in (_covered(registry, doc) - quoted).items():
            problems.append(f"{doc}: {number} registered {count} more time(s) than the doc quotes it")
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


def _covered(registry: Dict[str, Any], doc: str) -> Counter:
    """The numbers ``quoted``, ``settings`` and ``unchecked`` register for a doc, each as often as it is listed."""
    numbers: Counter = Counter()
    for kind in ("quoted", "settings", "unchecked"):
        for ns in registry[kind].get(doc, {}).values():
            numbers.update(ns)
    return numbers


def _uncovered_text(doc: str, registry: Dict[str, Any], root: Path) -> str:
    """A doc's text with every rendered entry text and allowlisted phrase blanked (lines kept)."""
    text = (root / doc).read_text()
    phrases = [render(e, root) for e in registry["figures"] if e["doc"] == doc] + registry["allow"].get(doc, [])
    for phrase in sorted(phrases, key=len, reverse=True):
        text = text.replace(phrase, re.sub(r"[^\n]", " ", phrase))
    return text


def unregistered(registry: Dict[str, Any], names: Iterable[str], root: Path = ROOT) -> List[str]:
    """Numbers of ``names`` that read as results and that nothing covers: no entry text or allowlisted phrase, no
    ``quoted``, ``settings`` or ``unchecked`` registration (each covers one occurrence)."""
    found = []
    for doc in names:
        text = _uncovered_text(doc, registry, root)
        covered = _covered(registry, doc)
        for number, at in figures_in(text):
            if covered[number] > 0:
                covered[number] -= 1
                continue
            line = text.count("\n", 0, at) + 1
            held = ", ".join(holders(doc, text, at, number, root)) or "no file its paragraph links"
            found.append(f"{doc}:{line}: {number!r} in ...{text[max(0, at - 40) : at + 20]!r}... (held by: {held})")
    return found


LINK = re.compile(r"\]\(([^)#\s]+)|(?<![\w/.])(results/[\w./-]+)")


def holders(doc: str, text: str, at: int, number: str, root: Path = ROOT) -> List[str]:
    """Where to register an unregistered number: the data files (and CSV columns) that the paragraph around offset
    ``at`` (a table's with its caption) links and that hold ``number``."""
    start, end = text.rfind("\n\n", 0, at) + 1, text.find("\n\n", at)
    if text[text.rfind("\n", 0, at) + 1 :].lstrip().startswith("|"):  # a table: its caption paragraph too
        start = text.rfind("\n\n", 0, max(start - 1, 0)) + 1
    found = []
    for link in LINK.finditer(text[start : end if end >= 0 else None]):
        target = link.group(1) or link.group(2)
        path = next((p for p in ((root / doc).parent / target, root / target) if p.exists()), None)
        if path is None or not path.absolute().is_relative_to(root.absolute() / "results"):
            continue
        folder = path.parent if path.name == "README.md" else path
        for data in sorted(folder.rglob("*")) if folder.is_dir() else [folder]:
            if data.suffix not in DATA or data.name == "README.md" or not holds(data, number):
                continue
            name = data.absolute().relative_to(root.absolute()).as_posix()  # not resolved: a test's copy links files
            columns = [c for c in _rows(data)[0] if c and holds(data, number, c)] if data.suffix == ".csv" else []
            found += [f"{name}#{c}" for c in columns] or [name]
    return list(dict.fromkeys(found))
