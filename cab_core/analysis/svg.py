"""Small inline-SVG charts for self-contained HTML pages (no plotting dependency, no CDN).

Each function returns one ``<svg>`` element as a string; every label is escaped.
"""
from __future__ import annotations

from html import escape

PALETTE = ("#4e79a7", "#f28e2b", "#e15759", "#76b7b2", "#59a14f", "#edc948", "#b07aa1", "#ff9da7", "#9c755f",
           "#bab0ac")
FONT = 'font-family="sans-serif" font-size="11"'


def _frame(w: int, h: int, body: list[str], title: str) -> str:
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img" '
            f'aria-label="{escape(title)}"><title>{escape(title)}</title>{"".join(body)}</svg>')


def _text(x: float, y: float, s: str, anchor: str = "start", extra: str = "") -> str:
    return f'<text x="{x:.1f}" y="{y:.1f}" text-anchor="{anchor}" {FONT} {extra}>{escape(str(s))}</text>'


def hbars(title: str, rows: list[tuple[str, float, tuple[float, float] | None]], xmax: float = 1.0,
          fmt=lambda v: f"{100 * v:.1f}%") -> str:
    """Horizontal bars (label, value, optional interval drawn as a whisker), value axis 0..xmax."""
    left, width, bar = 220, 360, 18
    h = 30 + bar * 1.5 * len(rows) + 20
    body = [_text(left, 14, title, extra='font-weight="bold"')]
    for i, (label, v, ci) in enumerate(rows):
        y = 26 + i * bar * 1.5
        wv = width * (v / xmax if xmax else 0)
        body.append(_text(left - 6, y + bar * 0.75, label, "end"))
        body.append(f'<rect x="{left}" y="{y:.1f}" width="{wv:.1f}" height="{bar}" fill="{PALETTE[0]}"/>')
        if ci is not None:
            x0, x1 = left + width * ci[0] / xmax, left + width * ci[1] / xmax
            ym = y + bar / 2
            body.append(f'<path d="M{x0:.1f},{ym:.1f}H{x1:.1f}M{x0:.1f},{ym - 5:.1f}v10M{x1:.1f},{ym - 5:.1f}v10" '
                        f'stroke="#222" fill="none"/>')
        body.append(_text(left + max(wv, width * (ci[1] / xmax if ci else 0)) + 6, y + bar * 0.75, fmt(v)))
    return _frame(left + width + 90, int(h), body, title)


def stacked(title: str, rows: list[tuple[str, list[float]]], parts: list[str]) -> str:
    """Horizontal stacked bars of counts (each row its own total), with a legend of ``parts``."""
    left, width, bar = 220, 360, 18
    total = max([sum(v) for _, v in rows] + [1])
    cols = 3
    h = 30 + bar * 1.5 * len(rows) + 20 * ((len(parts) + cols - 1) // cols) + 10
    body = [_text(left, 14, title, extra='font-weight="bold"')]
    for i, (label, vals) in enumerate(rows):
        y = 26 + i * bar * 1.5
        x = left
        body.append(_text(left - 6, y + bar * 0.75, label, "end"))
        for j, v in enumerate(vals):
            w = width * v / total
            if v:
                body.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{w:.1f}" height="{bar}" '
                            f'fill="{PALETTE[j % len(PALETTE)]}"><title>{escape(parts[j])}: {v:g}</title></rect>')
                if w > 16:
                    body.append(_text(x + w / 2, y + bar * 0.75, f"{v:g}", "middle", 'fill="#fff"'))
            x += w
    ly = 26 + len(rows) * bar * 1.5 + 8
    for j, p in enumerate(parts):
        lx, lyy = left + (j % cols) * 190, ly + (j // cols) * 20
        body.append(f'<rect x="{lx}" y="{lyy:.1f}" width="10" height="10" fill="{PALETTE[j % len(PALETTE)]}"/>')
        body.append(_text(lx + 14, lyy + 9, p))
    return _frame(left + max(width, cols * 190) + 40, int(h), body, title)


def lines(title: str, series: list[tuple[str, list[float | None]]], xlabel: str, ylabel: str) -> str:
    """Line chart of series over x = 0, 1, 2, ... (values in 0..1), with a legend."""
    left, top, width, height = 50, 24, 460, 220
    n = max([len(v) for _, v in series] + [2])
    body = [_text(left, 14, title, extra='font-weight="bold"'),
            f'<path d="M{left},{top}V{top + height}H{left + width}" stroke="#444" fill="none"/>']
    for t in (0, 0.25, 0.5, 0.75, 1.0):
        y = top + height * (1 - t)
        body.append(_text(left - 4, y + 4, f"{int(t * 100)}%", "end"))
        body.append(f'<path d="M{left},{y:.1f}H{left + width}" stroke="#ddd"/>')
    for t in range(0, n, max(1, n // 8)):
        body.append(_text(left + width * t / (n - 1), top + height + 14, str(t), "middle"))
    body.append(_text(left + width / 2, top + height + 30, xlabel, "middle"))
    body.append(_text(12, top + height / 2, ylabel, "middle", f'transform="rotate(-90 12 {top + height / 2})"'))
    for i, (label, vals) in enumerate(series):
        pts = [f"{left + width * k / (n - 1):.1f},{top + height * (1 - v):.1f}" for k, v in enumerate(vals) if v is not None]
        color = PALETTE[i % len(PALETTE)]
        if pts:
            body.append(f'<polyline points="{" ".join(pts)}" fill="none" stroke="{color}" stroke-width="2"/>')
        body.append(f'<rect x="{left + width + 10}" y="{top + i * 16}" width="10" height="10" fill="{color}"/>')
        body.append(_text(left + width + 24, top + i * 16 + 9, label))
    return _frame(left + width + 250, top + height + 40, body, title)


def scatter(title: str, points: list[tuple[str, float, float]], xlabel: str, ylabel: str) -> str:
    """Labelled points (label, x, y in 0..1); the x axis spans 0..max x."""
    left, top, width, height = 50, 24, 420, 220
    xmax = max([p[1] for p in points] + [1e-9]) * 1.1
    body = [_text(left, 14, title, extra='font-weight="bold"'),
            f'<path d="M{left},{top}V{top + height}H{left + width}" stroke="#444" fill="none"/>',
            _text(left + width / 2, top + height + 30, xlabel, "middle"),
            _text(12, top + height / 2, ylabel, "middle", f'transform="rotate(-90 12 {top + height / 2})"'),
            _text(left + width, top + height + 14, f"{xmax:.3g}", "end"), _text(left, top + height + 14, "0", "middle")]
    for t in (0, 0.5, 1.0):
        body.append(_text(left - 4, top + height * (1 - t) + 4, f"{int(t * 100)}%", "end"))
    for i, (label, x, y) in enumerate(points):
        px, py = left + width * x / xmax, top + height * (1 - y)
        body.append(f'<circle cx="{px:.1f}" cy="{py:.1f}" r="5" fill="{PALETTE[i % len(PALETTE)]}"/>')
        body.append(_text(px + 7, py - 6, label))
    return _frame(left + width + 160, top + height + 40, body, title)


def grouped_hbars(title: str, rows: list[tuple[str, list[tuple[float | None, tuple[float, float] | None]]]],
                  series: list[str], fmt=lambda v: f"{100 * v:.1f}%") -> str:
    """Horizontal bars in groups: one group per row label, one bar per series (value in 0..1,
    optional interval drawn as a whisker; a None value draws no bar and writes "–"), with a legend
    of ``series``."""
    left, width, bar = 220, 360, 14
    group = bar * (len(series) + 0.8)
    cols = 3
    legend_rows = (len(series) + cols - 1) // cols
    h = 30 + group * len(rows) + 20 * legend_rows + 10
    body = [_text(left, 14, title, extra='font-weight="bold"')]
    for i, (label, vals) in enumerate(rows):
        y0 = 26 + i * group
        body.append(_text(left - 6, y0 + bar * len(series) / 2 + 4, label, "end"))
        for j, (v, ci) in enumerate(vals):
            y = y0 + j * bar
            color = PALETTE[j % len(PALETTE)]
            name = f"{label}, {series[j]}" if j < len(series) else label
            if v is None:
                body.append(_text(left + 4, y + bar * 0.8, "–"))
                continue
            wv = width * v
            body.append(f'<rect x="{left}" y="{y:.1f}" width="{wv:.1f}" height="{bar - 2}" fill="{color}">'
                        f'<title>{escape(name)}: {escape(fmt(v))}</title></rect>')
            if ci is not None:
                x0, x1 = left + width * ci[0], left + width * ci[1]
                ym = y + (bar - 2) / 2
                body.append(f'<path d="M{x0:.1f},{ym:.1f}H{x1:.1f}M{x0:.1f},{ym - 4:.1f}v8M{x1:.1f},{ym - 4:.1f}v8" '
                            f'stroke="#222" fill="none"/>')
            body.append(_text(left + max(wv, width * (ci[1] if ci else 0)) + 6, y + bar * 0.8, fmt(v)))
    ly = 26 + len(rows) * group + 8
    for j, s in enumerate(series):
        lx, lyy = left + (j % cols) * 190, ly + (j // cols) * 20
        body.append(f'<rect x="{lx}" y="{lyy:.1f}" width="10" height="10" fill="{PALETTE[j % len(PALETTE)]}"/>')
        body.append(_text(lx + 14, lyy + 9, s))
    return _frame(left + max(width + 90, cols * 190) + 40, int(h), body, title)
