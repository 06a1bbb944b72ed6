"""PIL drawing helpers for annotated observations (marks, gripper previews, legends).

All coordinates are pixels [u, v] of the image being drawn on (top-left origin, u right, v down).
Drawing never changes the source observation: a :class:`Canvas` works on a copy and ``image()``
returns a new uint8 HxWx3 array.
"""
from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, ImageDraw, ImageFont

if TYPE_CHECKING:  # the annotation only: a run-time import would add a level below the tools
    from cab_core.geometry import Vector


# Distinct, named colours for numbered marks and candidates (name reported to the agent).
PALETTE: tuple[tuple[str, tuple[int, int, int]], ...] = (
    ("red", (230, 25, 75)), ("green", (60, 180, 75)), ("blue", (0, 130, 200)), ("orange", (245, 130, 48)),
    ("magenta", (240, 50, 230)), ("cyan", (70, 240, 240)), ("yellow", (255, 225, 25)), ("purple", (145, 30, 180)),
    ("lime", (210, 245, 60)), ("pink", (250, 190, 212)), ("teal", (0, 128, 128)), ("brown", (170, 110, 40)),
)
AXIS_COLOURS = {"x": (230, 25, 75), "y": (60, 180, 75), "z": (0, 130, 200)}
_CLIP = 1e5  # keep wildly off-screen coordinates finite for PIL


@functools.lru_cache(maxsize=8)
def font(size: int = 12) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def in_frame(px: Vector | None, size_hw: Sequence[int]) -> bool:
    """Whether a pixel lies inside an image of size [H, W]."""
    if px is None:
        return False
    u, v = float(px[0]), float(px[1])
    return bool(np.isfinite(u) and np.isfinite(v) and 0.0 <= u < size_hw[1] and 0.0 <= v < size_hw[0])


def _pt(p: Sequence[float]) -> tuple[float, float]:
    return (float(np.clip(p[0], -_CLIP, _CLIP)), float(np.clip(p[1], -_CLIP, _CLIP)))


def convex_hull(points: Iterable[Sequence[float]]) -> list[tuple[float, float]]:
    """Monotone-chain convex hull of 2D points, counter-clockwise, no repeated end point."""
    pts = sorted({(float(p[0]), float(p[1])) for p in points})
    if len(pts) <= 2:
        return pts

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower: list[tuple[float, float]] = []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    upper: list[tuple[float, float]] = []
    for p in reversed(pts):
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return lower[:-1] + upper[:-1]


class Canvas:
    """An RGBA drawing layer over a copy of an RGB image."""

    def __init__(self, image: np.ndarray):
        self.base = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8), "RGB").convert("RGBA")
        self.layer = Image.new("RGBA", self.base.size, (0, 0, 0, 0))
        self.draw = ImageDraw.Draw(self.layer)
        self.size_hw = [self.base.size[1], self.base.size[0]]

    def image(self) -> np.ndarray:
        return np.asarray(Image.alpha_composite(self.base, self.layer).convert("RGB"), dtype=np.uint8).copy()

    # -- primitives ---------------------------------------------------------------------------
    def line(self, a, b, colour, width: int = 2, alpha: int = 255) -> None:
        self.draw.line([_pt(a), _pt(b)], fill=(*colour, alpha), width=width)

    def polyline(self, pts, colour, width: int = 2, alpha: int = 255) -> None:
        if len(pts) >= 2:
            self.draw.line([_pt(p) for p in pts], fill=(*colour, alpha), width=width)

    def polygon(self, pts, colour, fill_alpha: int = 70, outline_alpha: int = 255, width: int = 2) -> None:
        if len(pts) >= 3:
            q = [_pt(p) for p in pts]
            self.draw.polygon(q, fill=(*colour, fill_alpha))
            self.draw.line(q + [q[0]], fill=(*colour, outline_alpha), width=width)

    def circle(self, c, r: float, colour, fill: bool = False, width: int = 2, alpha: int = 255) -> None:
        u, v = _pt(c)
        box = [u - r, v - r, u + r, v + r]
        if fill:
            self.draw.ellipse(box, fill=(*colour, alpha), outline=(0, 0, 0, 255), width=1)
        else:
            self.draw.ellipse(box, outline=(*colour, alpha), width=width)

    def cross(self, c, r: float, colour, width: int = 2) -> None:
        u, v = _pt(c)
        self.line((u - r, v), (u + r, v), colour, width)
        self.line((u, v - r), (u, v + r), colour, width)

    def arrow(self, a, b, colour, width: int = 2, head: float = 8.0) -> None:
        a, b = np.asarray(_pt(a)), np.asarray(_pt(b))
        self.line(a, b, colour, width)
        d = b - a
        n = float(np.linalg.norm(d))
        if n < 1e-6:
            return
        d /= n
        perp = np.array([-d[1], d[0]])
        h = min(head, 0.5 * n)
        tip = [tuple(b), tuple(b - h * d + 0.5 * h * perp), tuple(b - h * d - 0.5 * h * perp)]
        self.draw.polygon(tip, fill=(*colour, 255))

    def text_size(self, text: str, size: int = 12) -> tuple[float, float]:
        """Width and height of a label box for ``text``, pixels."""
        x1, y1, x2, y2 = self.draw.textbbox((0, 0), text, font=font(size))
        return x2 - x1 + 4, y2 - y1 + 4

    def text(self, xy, text: str, colour=(255, 255, 255), size: int = 12, box: bool = True) -> list[int]:
        """Draw ``text`` with its top-left corner at ``xy`` on a dark box, kept inside the image.
        Returns the label box [x1, y1, x2, y2] in pixels."""
        f = font(size)
        x1, y1, _, _ = self.draw.textbbox((0, 0), text, font=f)
        w, h = self.text_size(text, size)
        x = float(np.clip(xy[0], 0, max(0, self.size_hw[1] - w)))
        y = float(np.clip(xy[1], 0, max(0, self.size_hw[0] - h)))
        if box:
            self.draw.rectangle([x, y, x + w, y + h], fill=(0, 0, 0, 170))
        self.draw.text((x + 2 - x1, y + 2 - y1), text, font=f, fill=(*colour, 255))
        return [int(round(x)), int(round(y)), int(round(x + w)), int(round(y + h))]

    # -- composite glyphs ---------------------------------------------------------------------
    def numbered_marker(self, px, number: int, label: str, colour) -> list[int]:
        """A ringed dot with its number and label beside it; returns the label box."""
        r = 6
        self.circle(px, r + 3, (0, 0, 0), width=2)
        self.circle(px, r, colour, fill=True)
        u, v = _pt(px)
        text = f"{number}: {label}" if label else str(number)
        w, h = self.text_size(text)
        x = u + r + 5 if u + r + 5 + w <= self.size_hw[1] else u - r - 5 - w  # beside the dot, inside the image
        y = v - h / 2 if v - h / 2 >= 0 else v + r + 3
        if y + h > self.size_hw[0]:
            y = v - r - 3 - h
        return self.text((x, y), text, colour=colour)

    def world_frame_legend(self, corner: str = "bottom_left") -> list[int]:
        """A schematic axis glyph (display-only: not aligned with the projected world axes)."""
        h, w = self.size_hw
        bw, bh = 160, 96
        x0 = 6 if "left" in corner else w - bw - 6
        y0 = h - bh - 6 if "bottom" in corner else 6
        self.draw.rectangle([x0, y0, x0 + bw, y0 + bh], fill=(0, 0, 0, 160), outline=(255, 255, 255, 200))
        o = (x0 + 28, y0 + 62)
        self.arrow(o, (o[0] + 34, o[1]), AXIS_COLOURS["x"])
        self.arrow(o, (o[0] + 20, o[1] - 20), AXIS_COLOURS["y"])
        self.arrow(o, (o[0], o[1] - 40), AXIS_COLOURS["z"])
        self.text((x0 + 66, y0 + 6), "+x  right", AXIS_COLOURS["x"], size=12, box=False)
        self.text((x0 + 66, y0 + 23), "+y  forward", AXIS_COLOURS["y"], size=12, box=False)
        self.text((x0 + 66, y0 + 40), "+z  up", AXIS_COLOURS["z"], size=12, box=False)
        self.text((x0 + 66, y0 + 57), "metres", (255, 255, 255), size=12, box=False)
        self.text((x0 + 4, y0 + bh - 17), "legend only, not to scale", (210, 210, 210), size=11, box=False)
        return [x0, y0, x0 + bw, y0 + bh]
