"""The report's figures, drawn with matplotlib: inline SVG for the pages, PDF/SVG/PNG files for papers.

Every figure is a :class:`CabFigure` (a :class:`matplotlib.figure.Figure` that holds its name,
title and marks' tooltips) made without pyplot (no global state, no GUI
backend: the Agg canvas), inside :func:`style` (fixed fonts and sizes, the SVG id salt), so that
the same data draws the same bytes every time: the files carry no date and no software version.

* :func:`inline_svg` gives the ``<svg>`` element a page embeds: no XML prolog, no metadata, and
  every ``id`` prefixed with the figure's name, so that several figures coexist on one page; the
  root carries ``role="img"``, an ``aria-label`` and a ``<title>`` (the figure's title), and
  ``data-figure`` (its name).
* :func:`write_files` writes ``<folder>/<name>.pdf``, ``.svg`` and ``.png`` of each figure.

The marks a reader (or a test) may look for carry ids (matplotlib's ``gid``): ``<name>-bar-<i>``,
``<name>-seg-<i>-<j>`` (row ``i``, part ``j`` of stacked bars), ``<name>-line-<i>``,
``<name>-point-<i>``; each such group holds a ``<title>`` saying what it shows (a tooltip in a
browser). Bars and points are numbered in the order the rows are given (top to bottom).

This module imports matplotlib when it is imported: the report imports it only when it draws.
"""
from __future__ import annotations

import io
import re
from contextlib import contextmanager
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg", force=False)  # noqa: E402  (no GUI backend, ever; pyplot is never imported here)
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.layout_engine import ConstrainedLayoutEngine  # noqa: E402

if TYPE_CHECKING:  # pragma: no cover  (the names of matplotlib's settings: its stubs only)
    from matplotlib.typing import RcKeyType

PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f",
           "#bab0ac")
FORMATS = ("pdf", "svg", "png")
PNG_DPI = 200
WIDTH = 6.4  # inches: one column of a two-column paper page is ~3.3, a full width ~6.5-7
# matplotlib's bundled DejaVu Sans (no font search, no download); text stays text in SVG (the
# browser draws it, the page stays small), fonts are embedded as TrueType in PDF
STYLE: dict[RcKeyType, Any] = {"font.family": "DejaVu Sans", "font.size": 9, "axes.titlesize": 10, "axes.titleweight": "bold",
         "svg.fonttype": "none", "pdf.fonttype": 42, "svg.hashsalt": "cab", "axes.spines.top": False,
         "axes.spines.right": False, "legend.frameon": False, "figure.dpi": 100, "path.simplify": False}
# no date, no software version: the files of the same report are the same bytes
METADATA: dict[str, dict[str, str | None]] = {"svg": {"Date": None, "Creator": None, "Format": None, "Type": None},
            "pdf": {"CreationDate": None, "ModDate": None, "Creator": None, "Producer": None},
            "png": {"Software": None}}
NO_DATA = "no data"


@contextmanager
def style(name: str = ""):
    """matplotlib's settings for drawing figure ``name`` (its SVG ids salted with the name)."""
    with matplotlib.rc_context({**STYLE, "svg.hashsalt": f"cab-{name}"}):
        yield


class CabFigure(Figure):
    """A report figure: matplotlib's figure with what the report's outputs need of it."""

    def __init__(self, name: str, title: str, height: float):
        super().__init__(figsize=(WIDTH, height), layout="constrained")
        self.cab_name = name  # the files' names, the SVG ids' prefix
        self.cab_title = title  # the files' Title metadata, the page's aria-label
        self.cab_titles: dict[str, str] = {}  # a marked group's gid -> its <title> (the tooltip)
        self.cab_svg: str | None = None  # the standalone SVG, once drawn (see svg_file)


def _figure(name: str, title: str, rows: int, extra: float = 0.0) -> tuple[CabFigure, Axes]:
    fig = CabFigure(name, title, 1.0 + 0.32 * max(rows, 1) + extra)
    ax = fig.add_subplot()
    ax.set_title(title, loc="left")
    return fig, ax


def _tip(fig: CabFigure, artist, gid: str, text: str) -> None:
    artist.set_gid(gid)
    fig.cab_titles[gid] = text


def _pct_axis(ax: Axes, axis: str = "x") -> None:
    from matplotlib.ticker import PercentFormatter

    (ax.xaxis if axis == "x" else ax.yaxis).set_major_formatter(PercentFormatter(1.0, decimals=0))
    (ax.set_xlim if axis == "x" else ax.set_ylim)(0, 1)


def _labels(ax: Axes, labels: list[str]) -> None:
    ax.set_yticks(range(len(labels)), labels)
    ax.set_ylim(max(len(labels), 1) - 0.5, -0.5)  # the first row on top
    if not labels:
        ax.text(0.5, 0.5, NO_DATA, transform=ax.transAxes, ha="center", va="center", color="#777")


def pct(v: float) -> str:
    return f"{100 * v:.1f}%"


def hbars(name: str, title: str, rows: list[tuple[str, float, tuple[float, float] | None]]) -> CabFigure:
    """Horizontal bars of shares (label, value in 0..1, optional interval drawn as a whisker)."""
    with style(name):
        fig, ax = _figure(name, title, len(rows))
        for i, (label, v, ci) in enumerate(rows):
            (bar,) = ax.barh(i, v, height=0.6, color=PALETTE[0])
            _tip(fig, bar, f"{name}-bar-{i}",
                 f"{label}: {pct(v)}" + (f" (interval {pct(ci[0])}–{pct(ci[1])})" if ci else ""))
            _whisker_and_value(ax, v, i, ci, capsize=3, lw=1, fontsize=8)
        _labels(ax, [r[0] for r in rows])
        _pct_axis(ax)
        ax.set_xlim(0, 1.12)
    return fig


def _whisker_and_value(ax: Axes, v: float, y: float, ci, capsize: float, lw: float, fontsize: float) -> None:
    """A share's interval as a whisker (when given) and its value written just past the bar."""
    if ci is not None:
        ax.errorbar(v, y, xerr=[[max(v - ci[0], 0)], [max(ci[1] - v, 0)]], fmt="none", ecolor="#222",
                    capsize=capsize, lw=lw)
    ax.text(max(v, ci[1] if ci else 0) + 0.01, y, pct(v), va="center", fontsize=fontsize)


def stacked(name: str, title: str, rows: list[tuple[str, list[float]]], parts: list[str]) -> CabFigure:
    """Horizontal stacked bars of counts (each row its own total), with a legend of ``parts``."""
    with style(name):
        fig, ax = _figure(name, title, len(rows), extra=0.25 * ((len(parts) + 2) // 3))
        for i, (label, vals) in enumerate(rows):
            left = 0.0
            for j, v in enumerate(vals):
                if v:
                    (seg,) = ax.barh(i, v, left=left, height=0.6, color=PALETTE[j % len(PALETTE)])
                    _tip(fig, seg, f"{name}-seg-{i}-{j}", f"{label}, {parts[j]}: {v:g}")
                    ax.text(left + v / 2, i, f"{v:g}", ha="center", va="center", color="white", fontsize=8)
                left += v
        _labels(ax, [r[0] for r in rows])
        from matplotlib.ticker import MaxNLocator

        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("attempts")
        from matplotlib.patches import Patch

        fig.legend([Patch(color=PALETTE[j % len(PALETTE)]) for j in range(len(parts))], parts, loc="outside lower left",
                   ncols=3, fontsize=8)
    return fig


def grouped_hbars(name: str, title: str, rows: list[tuple[str, list[tuple[float | None, tuple[float, float] | None]]]],
                  series: list[str]) -> CabFigure:
    """Horizontal bars in groups: one group per row label, one bar per series (value in 0..1,
    optional interval drawn as a whisker; a None value draws no bar and writes "–"), with a legend
    of ``series``. Bars are numbered in order over the bars drawn: ``<name>-bar-<k>``."""
    n = max(len(series), 1)
    h = 0.8 / n
    with style(name):
        fig, ax = _figure(name, title, len(rows) * max(1, n // 2), extra=0.25 * ((len(series) + 1) // 2))
        k = 0
        for i, (label, vals) in enumerate(rows):
            for j, (v, ci) in enumerate(vals):
                y = i - 0.4 + h * (j + 0.5)
                if v is None:
                    ax.text(0.01, y, "–", va="center", fontsize=8)
                    continue
                (bar,) = ax.barh(y, v, height=h * 0.9, color=PALETTE[j % len(PALETTE)])
                _tip(fig, bar, f"{name}-bar-{k}", f"{label}, {series[j] if j < len(series) else ''}: {pct(v)}")
                k += 1
                _whisker_and_value(ax, v, y, ci, capsize=2, lw=0.8, fontsize=7)
        _labels(ax, [r[0] for r in rows])
        _pct_axis(ax)
        ax.set_xlim(0, 1.12)
        from matplotlib.patches import Patch

        fig.legend([Patch(color=PALETTE[j % len(PALETTE)]) for j in range(len(series))], series,
                   loc="outside lower left", ncols=2, fontsize=8)
    return fig


def lines(name: str, title: str, series: list[tuple[str, list[float | None]]], xlabel: str, ylabel: str) -> CabFigure:
    """Line chart of shares (0..1) over x = 0, 1, 2, ..., one line per series, with a legend."""
    with style(name):
        fig, ax = _figure(name, title, 8)
        for i, (label, vals) in enumerate(series):
            pts = [(k, v) for k, v in enumerate(vals) if v is not None]
            (line,) = ax.plot([p[0] for p in pts], [p[1] for p in pts], color=PALETTE[i % len(PALETTE)], lw=1.6,
                              label=label, drawstyle="steps-post")  # the value after call k holds until call k+1
            _tip(fig, line, f"{name}-line-{i}", f"{label}: {pct(pts[-1][1]) if pts else '–'} at the last call")
        _pct_axis(ax, "y")
        ax.set_ylim(-0.02, 1.02)  # a line at 0% or 100% stays in view
        ax.set_xlim(left=0)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(axis="y", color="#ddd", lw=0.6)
        if series:
            ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
        else:
            ax.text(0.5, 0.5, NO_DATA, transform=ax.transAxes, ha="center", va="center", color="#777")
    return fig


def scatter(name: str, title: str, points: list[tuple[str, float, float]], xlabel: str, ylabel: str,
            xfmt=lambda x: f"{x:.3g}") -> CabFigure:
    """Labelled points (label, x, y in 0..1); the x axis spans 0..max x."""
    with style(name):
        fig, ax = _figure(name, title, 8)
        marks, notes = [], []
        for i, (label, x, y) in enumerate(points):
            (pt,) = ax.plot([x], [y], "o", ms=6, color=PALETTE[i % len(PALETTE)])
            _tip(fig, pt, f"{name}-point-{i}", f"{label}: {xlabel} {xfmt(x)}, {ylabel} {pct(y)}")
            marks.append(pt)
            note = ax.annotate(label, (x, y), xytext=(5, 4), textcoords="offset points", fontsize=7,
                               arrowprops={"arrowstyle": "-", "color": "#999", "lw": 0.5, "shrinkA": 1, "shrinkB": 4})
            assert note.arrow_patch is not None  # made by annotate, as arrowprops are given
            note.arrow_patch.set_visible(False)  # a leader line only for a label moved away from its point
            notes.append(note)
        _pct_axis(ax, "y")
        ax.set_ylim(-0.02, 1.05)
        ax.set_xlim(0, max([p[1] for p in points] + [1e-9]) * 1.25)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(color="#eee", lw=0.6)
        _place_labels(fig, ax, marks, notes)
    return fig


def label_box(note, renderer):
    """The window extent of an annotation's text alone (matplotlib's own extent adds its arrow)."""
    from matplotlib.text import Text

    note.update_positions(renderer)
    return Text.get_window_extent(note, renderer)


def _place_labels(fig: CabFigure, ax: Axes, marks: list, notes: list, gap: float = 2.0) -> None:
    """Each point's label beside it where it overlaps no label placed before it, no other point and
    stays inside the axes: the first free place of the four corners around the point, then the same
    corners one, two... label heights further up or down (close or equal points get a stack of
    labels, each joined to its point by a thin leader line); where none is free, the place that
    overlaps least. Deterministic: the same points, the same places. Measured on the laid-out figure
    (the layout is made again when it is saved: ``gap`` points of air keep neighbours apart)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.transforms import Bbox

    if len(notes) < 2:
        return
    renderer = FigureCanvasAgg(fig).get_renderer()  # a canvas of its own: saving picks the format's anyway
    fig.draw_without_rendering()  # lays the figure out (constrained layout) as the first save will
    px = fig.dpi / 72.0
    frame = ax.get_window_extent(renderer)
    dots = [m.get_window_extent(renderer) for m in marks]
    placed: list[Bbox] = []

    def overlap(a: Bbox, b: Bbox) -> float:
        w = min(a.x1, b.x1) - max(a.x0, b.x0)
        h = min(a.y1, b.y1) - max(a.y0, b.y0)
        return w * h if w > 0 and h > 0 else 0.0

    for i, note in enumerate(notes):
        note.set_verticalalignment("bottom")
        height = label_box(note, renderer).height / px + gap  # points
        best, best_cost = None, None
        for k in range(12):
            for dx, sign in ((5, 1), (5, -1), (-5, 1), (-5, -1)):
                dy = sign * (4 + k * height) if sign > 0 else -(4 + (k + 1) * height - gap)
                note.xyann = (dx, dy)
                note.set_horizontalalignment("left" if dx > 0 else "right")
                box = label_box(note, renderer).padded(gap * px / 2)
                cost = sum(overlap(box, b) for b in placed) + sum(overlap(box, d) for j, d in enumerate(dots) if j != i)
                outside = box.width * box.height - overlap(box, frame)
                cost += outside
                if best_cost is None or cost < best_cost:
                    best, best_cost = (dx, dy, k), cost
                if cost == 0:
                    break
            if best_cost == 0:
                break
        assert best is not None  # the first place tried is always taken: best_cost starts as None
        note.xyann = best[:2]
        note.set_horizontalalignment("left" if best[0] > 0 else "right")
        note.arrow_patch.set_visible(best[2] > 0)
        placed.append(label_box(note, renderer).padded(gap * px / 2))


# ---------------------------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------------------------
def _save(fig: CabFigure, fmt: str) -> bytes:
    """The figure in ``fmt``. The first save lays it out (constrained layout, measured by the
    format's renderer); the SVG is always the first, so the page and every file share one layout."""
    if fmt != "svg" and fig.cab_svg is None:
        svg_file(fig)
    buf = io.BytesIO()
    meta = dict(METADATA[fmt])
    if fmt in ("svg", "pdf"):
        meta["Title"] = fig.cab_title
    with style(fig.cab_name):
        if fmt == "png":
            fig.savefig(buf, format=fmt, metadata=meta, dpi=PNG_DPI)
        else:
            fig.savefig(buf, format=fmt, metadata=meta)
        if isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine):
            fig.set_layout_engine("none")  # laid out once (the first save): the other formats keep it
    return buf.getvalue()


def _with_titles(fig: CabFigure, text: str) -> str:
    """The SVG with a ``<title>`` in each marked group (the tooltip saying what the mark shows)."""
    for gid, tip in fig.cab_titles.items():
        text = text.replace(f'<g id="{gid}">', f'<g id="{gid}"><title>{escape(tip)}</title>', 1)
    return text


def svg_file(fig: CabFigure) -> str:
    """The figure as a standalone SVG document (the file beside the report); drawn once per figure."""
    if fig.cab_svg is None:
        fig.cab_svg = _with_titles(fig, _save(fig, "svg").decode())
    return fig.cab_svg


def inline_svg(fig: CabFigure) -> str:
    """The figure as one ``<svg>`` element to embed in a page: no prolog, doctype or metadata; ids
    prefixed with the figure's name (those matplotlib gives, the marks' gids already have it)."""
    text = svg_file(fig)
    text = text[text.index("<svg"):]
    text = re.sub(r"\s*<metadata>.*?</metadata>", "", text, flags=re.S)
    prefix = f"{fig.cab_name}-"

    def fix(m: re.Match) -> str:
        ref = m.group(2)
        return m.group(0) if ref.startswith(prefix) else f"{m.group(1)}{prefix}{ref}"

    text = re.sub(r'(\bid=")([^"]+)', fix, text)
    text = re.sub(r'(href="#)([^"]+)', fix, text)
    text = re.sub(r"(url\(#)([^)]+)", fix, text)
    head = (f'<svg role="img" aria-label="{escape(fig.cab_title)}" data-figure="{escape(fig.cab_name)}"'
            f' class="figure"')
    return head + text[len("<svg"):].rstrip() + "\n"  # its <title> is matplotlib's (the metadata's Title)


def write_files(figs: list[CabFigure], folder: Path) -> list[Path]:
    """``<folder>/<name>.{pdf,svg,png}`` of every figure; the paths written, in order."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for fig in figs:
        for fmt in FORMATS:
            p = folder / f"{fig.cab_name}.{fmt}"
            if fmt == "svg":
                p.write_text(svg_file(fig))
            else:
                p.write_bytes(_save(fig, fmt))
            out.append(p)
    return out
