"""The summary at the top of BENCHMARKS.md: one table of headline rows, copied by code out of the sections' own tables.

Each chosen section has a small extractor (``EXTRACTORS``). It finds its table by the heading above the table and
the column labels, and its rows by their labels: the shipped defaults' names, read from the code that ships them
(``shipped``). It never uses line numbers. A section that is absent, or whose table lacks the row or the column,
gives no summary row, so the summary never shows a number that its section does not print. ``with_summary``
rebuilds the block in a file's text. ``write_summary`` writes it, and ``lsr.eval.sections`` calls it after every
section it writes.
"""

from __future__ import annotations

import dataclasses
import fnmatch
import functools
import re
import statistics
import unicodedata
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lsr.errors import ConfigError
from lsr.eval.markers import around_block

SUMMARY_START, SUMMARY_END = "<!-- summary:start -->", "<!-- summary:end -->"
TITLE = "## Summary: the headline rows"
DASH = "–"
DRIVERS = "the drivers: driving detector vs judge"
"""The judged cross-identity table's row of the two detectors' agreement on the drivers (``lsr.eval.report``)."""
SELF, CROSS, JUDGED = "Self re-enactment", "Cross-identity re-enactment", "Moving parts, cross-identity"

_START = re.compile(r"^<!-- (\w+):([\w.-]+):start -->$", re.MULTILINE)
_NUMBER = re.compile(r"^[-+]?\d+(?:\.\d+)?")
_BRACKETED = re.compile(r"\(([-+]?\d+(?:\.\d+)?)\)")


@dataclasses.dataclass(frozen=True)
class Table:
    """One markdown table: the heading above it (without the #s), its column labels, its rows (label -> cell)."""
    heading: str
    columns: tuple[str, ...]
    rows: tuple[dict[str, str], ...]


@dataclasses.dataclass(frozen=True)
class Section:
    """The text between one section's markers (``lsr.eval.markers.markers``)."""
    name: str
    body: str

    def _first(self, pattern: str) -> str:
        found = re.search(pattern, self.body, re.MULTILINE)
        return found.group(1).strip() if found else ""

    @property
    def title(self) -> str:
        return self._first(r"^## (.+)$")

    @property
    def program(self) -> str:
        """The command that wrote the section, up to its first option ("lsr bench eyes")."""
        words = self._first(r"^```\n(.+)$").split()
        return " ".join(words[:next((i for i, w in enumerate(words) if w.startswith("-")), len(words))])

    @property
    def date(self) -> str:
        return self._first(r"^_Written by the command below on (\d{4}-\d{2}-\d{2})")

    def table(self, heading: str, *columns: str) -> Table | None:
        """The first table under a heading starting with ``heading`` that has all ``columns``."""
        return next((t for t in tables(self.body) if t.heading.startswith(heading) and set(columns) <= set(t.columns)),
                    None)


@dataclasses.dataclass(frozen=True)
class Headline:
    """One summary row: the measure, the default's value, a baseline's in the same run (cells as printed)."""
    section: Section
    measure: str
    default: str
    baseline: str = DASH


def sections(text: str) -> list[Section]:
    """Every section of ``text`` with both markers, in file order."""
    found = []
    for start in _START.finditer(text):
        end = text.find(f"<!-- {start.group(1)}:{start.group(2)}:end -->", start.end())
        if end >= 0:
            found.append(Section(start.group(2), text[start.end():end]))
    return found


def _cells(line: str) -> list[str]:
    line = line.strip()
    return [cell.strip() for cell in line[1:-1 if line.endswith("|") else None].split("|")]


def tables(body: str) -> list[Table]:
    """The markdown tables of ``body`` (a header line, a ``|---|`` line, the rows), each with the heading above it."""
    found, heading, block = [], "", []
    for line in [*body.splitlines(), ""]:
        if line.startswith("|"):
            block.append(line)
            continue
        if len(block) >= 2 and set("".join(_cells(block[1]))) <= set("-:"):
            columns = _cells(block[0])
            padded = (_cells(row) + [""] * len(columns) for row in block[2:])  # a short row: every label still there
            found.append(Table(heading, tuple(columns), tuple(dict(zip(columns, cells)) for cells in padded)))
        block = []
        if line.startswith("#"):
            heading = line.lstrip("#").strip()
    return found


def number(cell: str | None) -> str | None:
    """The number a cell starts with, as printed ("169 (camera grab ...)" -> "169"); None for –, n/a, inf."""
    found = _NUMBER.match(cell or "")
    return found.group(0) if found else None


def bracketed(cell: str | None) -> str | None:
    """The number in a cell's brackets ("0.029 (1.18)" -> "1.18")."""
    found = _BRACKETED.search(cell or "")
    return found.group(1) if found else None


def _key(column: str) -> Callable[[float], float] | None:
    """Sort key whose smallest is best, from the column label's arrow (↑ higher, ↓ lower, →1 nearest 1)."""
    if column.endswith("↑"):
        return lambda value: -value
    if column.endswith("↓"):
        return lambda value: value
    return (lambda value: abs(value - 1.0)) if column.endswith("→1") else None


@functools.cache
def shipped() -> dict[str, Any]:
    """The defaults whose rows are the headline's, read from the code that ships them."""
    from lsr.config.eval_options import EvalConfig
    from lsr.config.inference import ReenactConfig
    from lsr.core.engine import ReenactorBase
    from lsr.core.inputs import DEFAULT_K

    def default(config: type, name: str) -> Any:
        return next(field.default for field in dataclasses.fields(config) if field.name == name)

    return {"k": str(DEFAULT_K), "detector": default(ReenactConfig, "detector"),
            "baselines": default(EvalConfig, "methods"),
            **{name: getattr(ReenactorBase, name).default for name in ("eyes", "lids", "mouth_interior", "bank")}}


def protocol(scope: str, measures: tuple[tuple[str, str, str], ...]) -> Callable[[Section], list[Headline]]:
    """An ``lsr eval`` section's extractor: per (table heading, who, column) the default at K = the default K (the
    one ``lsr:`` method without a "+" variant) beside the best of ``lsr eval``'s no-learning baselines."""
    def extract(section: Section) -> list[Headline]:
        k, found = shipped()["k"], []
        for heading, who, column in measures:
            table = section.table(heading, "method", "K", column)
            rows = {row["method"]: row for row in (table.rows if table else ()) if row.get("K") == k}
            ours = {method for method in rows if method.startswith("lsr:") and "+" not in method}
            if len(ours) != 1 or number(rows[next(iter(ours))].get(column)) is None:
                continue
            label = f"{scope}, K = {k}, {who}: {column}"
            if number(rows.get(DRIVERS, {}).get(column)) is not None:
                label += f" (the detectors agree: {rows[DRIVERS][column]})"
            scored = [(float(number(rows[m].get(column))), m) for m in shipped()["baselines"]
                      if number(rows.get(m, {}).get(column)) is not None]
            key = _key(column)
            best = min(scored, key=lambda pair: key(pair[0])) if scored and key else None
            found.append(Headline(section, label, rows[next(iter(ours))][column],
                                  f"{rows[best[1]][column]} ({best[1]})" if best else DASH))
        return found
    return extract


def eyes(section: Section) -> list[Headline]:
    """``lsr bench eyes``: medians over the pairs of the default bank's judged eye r and realism (x floor) beside
    the synthesis' own eyes (bank "none"), with the detectors' agreement."""
    table = section.table("", "pair", "eyes from", "eye r", "realism ↓ (x floor)")
    pairs: dict[str, dict[str, dict[str, str]]] = {}
    pair = ""
    for row in table.rows if table else ():
        pair = row["pair"] or pair  # a pair's bank rows leave its cell empty
        pairs.setdefault(pair, {})[row["eyes from"]] = row
    bank, realism = shipped()["bank"], "realism ↓ (x floor)"

    def readable(rows: dict[str, dict[str, str]]) -> bool:  # the pair has every cell the row is made of
        return ("agreement / floor" in rows and number(rows["agreement / floor"].get("eye r")) is not None
                and all(label in rows and number(rows[label].get("eye r")) is not None
                        and bracketed(rows[label].get(realism)) is not None for label in (bank, "none")))

    complete = [rows for rows in pairs.values() if readable(rows)]
    if not complete:
        return []

    def median(label: str, column: str, read: Callable[[str], str | None] = number) -> str:
        return f"{statistics.median(float(read(rows[label][column])) for rows in complete):.2f}"

    def both(label: str) -> str:
        return f"eye r {median(label, 'eye r')}, realism {median(label, realism, bracketed)}x floor"

    measure = (f"eyes over whole clips, {section.name.removeprefix('eyes_')} ({len(complete)} pairs; medians): eye r "
               f"judged by dlib ↑ (the detectors agree: {median('agreement / floor', 'eye r')}), realism ↓")
    return [Headline(section, measure, f"{both(bank)} (bank {bank})", f"{both('none')} (the synthesis' eyes)")]


def speed(section: Section) -> list[Headline]:
    """``lsr bench speed``: per runtime, the network's and the whole path's ms per frame of the shipped weights."""
    weights = re.search(r"^- weights `([^`]+)`: `(?:[^`]*/)?weights/default` \((\d+)²", section.body, re.MULTILINE)
    table = section.table("", "preset", "res", "runtime", "ms/frame", "% conv peak", "total ms")
    if not weights or not table:
        return []
    rows = [row for row in table.rows if (row["preset"], row["res"]) == weights.groups()
            and number(row.get("ms/frame")) and number(row.get("total ms"))]
    scope = f"the shipped weights ({weights.group(1)}, {weights.group(2)}²), ms per frame"
    return [Headline(section, f"{scope}: the network ↓ (% of the conv peak)",
                     "; ".join(f"{row['ms/frame']} ({row['% conv peak']}) {row['runtime']}" for row in rows)),
            Headline(section, f"{scope}: the per-frame path, warps included ↓",
                     "; ".join(f"{row['total ms']} {row['runtime']}" for row in rows))] if rows else []


def reenact(section: Section) -> list[Headline]:
    """``lsr bench reenact``: end-to-end fps of the default options, per runtime."""
    table = section.table("", "runtime", "detector", "eyes", "lids", "mouth interior", "end-to-end fps")
    choices = {"detector": shipped()["detector"], "eyes": shipped()["eyes"], "lids": shipped()["lids"],
               "mouth interior": shipped()["mouth_interior"]}
    rows: dict[str, list[dict[str, str]]] = {}
    for row in table.rows if table else ():
        if all(row.get(column) == value for column, value in choices.items()) and number(row["end-to-end fps"]):
            rows.setdefault(row["runtime"], []).append(row)
    fps = [f"{found[0]['end-to-end fps']} ({runtime})" for runtime, found in rows.items() if len(found) == 1]
    measure = (f"end to end, the defaults ({choices['detector']} detector, {choices['eyes']} eyes, {choices['lids']} "
               f"lids, {choices['mouth interior']} mouth interior): frames per second ↑")
    return [Headline(section, measure, ", ".join(fps))] if fps else []


def _where(section: Section, label: str) -> dict[str, str] | None:
    table = section.table("", "where", "fps", "latency ms, median")
    return next((row for row in table.rows if row["where"].startswith(label) and number(row["fps"])
                 and number(row["latency ms, median"])), None) if table else None


def _fps(row: dict[str, str]) -> str:
    return f"{row['fps']} fps, {number(row['latency ms, median'])} ms"


def live(section: Section) -> list[Headline]:
    """``lsr bench live``: the webcam tab in a browser on the same cores."""
    row = _where(section, "browser and app")
    measure = "the live webcam tab in a browser: fps ↑, median latency ↓"
    return [Headline(section, measure, _fps(row))] if row else []


def web(section: Section) -> list[Headline]:
    """``lsr bench web``: the web site beside the app's live tab in the same run."""
    row, tab = _where(section, "the web site"), _where(section, "the app's live tab")
    return [Headline(section, "the web site, everything in the browser: fps ↑, median latency ↓", _fps(row),
                     f"{_fps(tab)} (the app's live tab)" if tab else DASH)] if row else []


def landmarks(section: Section) -> list[Headline]:
    """``lsr bench landmarks``: the default tracker's mean ms per frame beside the other's; the mesh's NME."""
    found, detector = [], shipped()["detector"]
    table = section.table("", "tracker", "stage", "mean ms/frame")
    tracking = [row for row in (table.rows if table else ()) if row["stage"].startswith("tracking")
                and number(row["mean ms/frame"])]
    ours = [row for row in tracking if row["tracker"].split(" ")[0] == detector]
    others = sorted((row for row in tracking if row not in ours), key=lambda row: float(number(row["mean ms/frame"])))
    if len(ours) == 1:
        found.append(Headline(section, f"landmarks, {ours[0]['tracker']}: tracking, detection amortised, mean ms per "
                              "frame ↓", ours[0]["mean ms/frame"],
                              f"{others[0]['mean ms/frame']} ({others[0]['tracker']})" if others else DASH))
    table = section.table("", "clip", "NME frontal")
    row = next((row for row in (table.rows if table else ()) if row["clip"] == "**all clips**"), None)
    if row and number(row["NME frontal"]):
        found.append(Headline(section, "landmarks, the mesh's 68 points against dlib's on the real clips' frontal "
                              "frames: NME ↓", row["NME frontal"]))
    return found


EXTRACTORS: tuple[tuple[str, Callable[[Section], list[Headline]]], ...] = (
    ("fsth_warp_guided", protocol("FSTH sample", (
        (SELF, "self", "PSNR ↑"), (SELF, "self", "PSNR face ↑"), (SELF, "self", "SSIM ↑"),
        (SELF, "self", "sharpness →1"), (CROSS, "cross-identity", "ID-SIM to source ↑"),
        (JUDGED, "cross-identity, judged by dlib", "mouth corr ↑")))),
    ("fsth_banks", protocol("FSTH sample, the eye bank of the K shots", (
        (JUDGED, "cross-identity, judged by dlib", "eye corr ↑"),))),
    ("clips_cross", protocol("shared clips", (
        (SELF, "self", "PSNR ↑"), (JUDGED, "cross-identity, judged by dlib", "mouth corr ↑"),
        (JUDGED, "cross-identity, judged by dlib", "eye corr ↑")))),
    ("eyes_*", eyes),
    ("speed", speed),
    ("reenact", reenact),
    ("live", live),
    ("web", web),
    ("landmarks", landmarks),
)
"""Section name (a glob) -> its extractor, in the summary's order; sections matching a glob in file order."""


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation and symbols dropped, spaces to hyphens."""
    kept = (c for c in heading.strip().lower() if c in " -_" or unicodedata.category(c)[0] in "LNM")
    return "".join(kept).replace(" ", "-")


def anchors(text: str) -> dict[str, str]:
    """Heading -> its anchor in ``text``, as GitHub numbers repeats (-1, -2 ...; the first of equal headings);
    the summary's own heading comes first."""
    seen: dict[str, int] = {}

    def unique(base: str) -> str:
        anchor = base
        while anchor in seen:
            seen[base] += 1
            anchor = f"{base}-{seen[base]}"
        seen[anchor] = 0
        return anchor

    unique(slug(TITLE.lstrip("# ")))
    found: dict[str, str] = {}
    fenced = False
    for line in text.splitlines():
        fenced = fenced != line.startswith("```")
        heading = re.match(r"#{1,6} (.+)$", line)
        if heading and not fenced:
            found.setdefault(heading.group(1).strip(), unique(slug(heading.group(1))))
    return found


def headlines(text: str) -> list[Headline]:
    """The summary's rows of ``text``'s sections (``EXTRACTORS``' order)."""
    found = sections(text)
    return [row for pattern, extract in EXTRACTORS for section in found if fnmatch.fnmatchcase(section.name, pattern)
            for row in extract(section)]


def summary_block(text: str) -> str:
    """The summary block, markers included, of ``text`` (a file without its summary)."""
    rows, where = headlines(text), anchors(text)
    lines = [SUMMARY_START, TITLE, "",
             "_Copied out of the sections below by `lsr.eval.sections.write_summary`, which every command that writes "
             "a section runs after it; edit nothing here. Values are the sections' cells as printed (eyes: medians "
             "over pairs); each section names its whole command and machine. Baseline: for `lsr eval` the best of "
             "the same run's no-learning baselines by the measure's arrow (↑ higher, ↓ lower, →1 nearest 1); "
             "elsewhere what the same run measured beside the default, named in brackets._", ""]
    if rows:
        lines += ["| measure | the default | baseline, same run | printed by |", "|---|---|---|---|"]
        lines += [f"| {row.measure} | {row.default} | {row.baseline} | [`{row.section.program}`]"
                  f"(#{where.get(row.section.title, '')}), {row.section.date} |" for row in rows]
    else:
        lines.append("No section below gives a headline row yet.")
    return "\n".join([*lines, SUMMARY_END]) + "\n"


def with_summary(text: str) -> str:
    """``text`` with its summary block rebuilt in place, or put before the first section; every byte outside the
    block is kept. A file without a block and without headline rows is returned as it is."""
    around = around_block(text, SUMMARY_START, SUMMARY_END, "one pair, or none: the summary is put back before the "
                          "first section")
    if around:
        before, after = around
        return before + summary_block(before + after) + after
    first = _START.search(text)
    if first is None or not headlines(text):
        return text
    return text[:first.start()] + summary_block(text) + "\n" + text[first.start():]


def write_summary(path: Path) -> Path:
    """Rebuild the summary block of the markdown file ``path`` from its sections (``with_summary``); atomic, and
    the file is left untouched when nothing changes."""
    from landmarks.io.image_files import atomic_output

    path = Path(path)
    text = path.read_text()
    try:
        updated = with_summary(text)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    if updated != text:
        with atomic_output(path) as temp:
            temp.write_text(updated)
    return path
