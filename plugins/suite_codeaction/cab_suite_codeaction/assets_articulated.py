"""Generated assets of the ``articulated`` task group: the laptop of ``open_laptop_setup_arm`` (a
two-link URDF on a friction hinge) and the shoe box and shoes of ``place_dual_shoes`` (primitive
and convex-mesh rigid bodies). Everything is built from code; nothing is downloaded.

Frames are documented per asset; quaternions are (w, x, y, z); metres and kilograms.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .common import box_inertia, srgb, urdf_inertial, urdf_part


# =================================================================================================
# laptop
# =================================================================================================
@dataclass(frozen=True)
class LaptopVariant:
    """One laptop model (as upstream's ``015_laptop`` ids, several sizes and finishes)."""
    width: float  # x, base and lid
    depth: float  # y, base and lid (hinge to front edge)
    base_t: float  # base thickness
    lid_t: float  # lid thickness
    shell_rgb: tuple[float, float, float]
    keys_rgb: tuple[float, float, float]
    logo_rgb: tuple[float, float, float]


LAPTOP_VARIANTS = (
    LaptopVariant(0.31, 0.215, 0.017, 0.007, (0.78, 0.79, 0.81), (0.12, 0.12, 0.13), (0.95, 0.95, 0.97)),  # silver 13"
    LaptopVariant(0.325, 0.225, 0.019, 0.008, (0.30, 0.31, 0.34), (0.08, 0.08, 0.09), (0.70, 0.72, 0.75)),  # grey 14"
    LaptopVariant(0.345, 0.235, 0.021, 0.009, (0.10, 0.10, 0.11), (0.04, 0.04, 0.05), (0.85, 0.10, 0.10)),  # black 15"
    LaptopVariant(0.30, 0.21, 0.016, 0.007, (0.86, 0.74, 0.68), (0.93, 0.93, 0.92), (0.98, 0.92, 0.88)),  # rose 13"
)
LID_UPPER = 2.2  # rad (126 deg): the hinge's full range is [0, LID_UPPER]
LID_MASS = 0.12  # kg (upstream sets 0.01 kg for the whole model)
BASE_MASS = 1.2  # kg (the root is fixed)
# A laptop's friction hinge holds the lid at any angle. PhysX's articulation joint friction is
# Coulomb-like (proportional to the joint's constraint force), so 1.0 holds the lid at every angle
# independently of its mass (measured: no drift in 5 s from 0.1 to 1.9 rad), while a push of a few
# newtons at the front edge opens it; a little damping stops a flung lid.
HINGE_FRICTION = 1.0
HINGE_DAMPING = 0.05


def laptop_geometry(v: LaptopVariant) -> dict[str, Any]:
    """Frames. Base link: origin at the bottom centre of the base, +x to the right, +y toward the
    hinge (back), +z up; the front edge is at y = -depth/2. Lid link: origin on the hinge axis (the
    base's back top edge), axes equal to the base's when closed; the closed lid spans
    y in [-depth, 0], z in [0, lid_t]; its inner face (screen) is z = 0, its front edge y = -depth.
    The hinge axis is the lid's -x: a positive angle lifts the front edge."""
    return {
        "hinge_base": (0.0, v.depth / 2, v.base_t),
        "edge_lid": (0.0, -v.depth, v.lid_t / 2),  # centre of the lid's front edge (contact point 1)
        "lid_center_lid": (0.0, -v.depth / 2, v.lid_t / 2),
    }


def lid_rotation(q: float) -> np.ndarray:
    """Rotation of the lid frame relative to the base frame at hinge angle ``q`` (about -x)."""
    c, s = np.cos(q), np.sin(q)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def laptop_urdf(v: LaptopVariant) -> str:
    """The laptop as a two-link URDF of primitives: ``base`` (body, keyboard deck, trackpad,
    hinge barrel) and ``lid`` (shell, screen, bezel, logo) on the revolute joint ``lid_hinge``."""
    W, D, B, T = v.width, v.depth, v.base_t, v.lid_t
    shell = srgb(*v.shell_rgb)
    keys = srgb(*v.keys_rgb)
    pad = srgb(*(np.asarray(v.shell_rgb) * 0.9 + 0.05))
    screen = srgb(0.05, 0.09, 0.16)
    bezel = srgb(0.03, 0.03, 0.035)
    logo = srgb(*v.logo_rgb)
    parts: list[str] = []

    def add(name: str, *a: Any, **k: Any) -> None:
        parts.append(urdf_part(*a, material=name, **k))

    add("shell", "box", (W, D, B), (0, 0, B / 2), rgba=shell)
    # keyboard: a dark deck with rows of keys (visual only, 0.5 mm proud of the top)
    kw, kd = W - 0.05, D * 0.42
    ky = D / 2 - 0.025 - kd / 2
    add("deck", "box", (kw, kd, 0.0006), (0, ky, B + 0.0003), rgba=srgb(*(np.asarray(v.keys_rgb) * 0.6)),
        collision=False)
    rows, cols = 5, 14
    key = (kw - 0.01) / cols
    for r in range(rows):
        for c in range(cols):
            if r == rows - 1 and 3 <= c < 10:
                continue  # the space bar goes here
            add("key", "box", (key * 0.8, kd / rows * 0.78, 0.0012),
                (-kw / 2 + 0.005 + key * (c + 0.5), ky + kd / 2 - kd / rows * (r + 0.5), B + 0.0006), rgba=keys,
                collision=False)
    add("key", "box", (key * 7 * 0.95, kd / rows * 0.78, 0.0012),
        (-kw / 2 + 0.005 + key * 6.5, ky + kd / 2 - kd / rows * (rows - 0.5), B + 0.0006), rgba=keys,
        collision=False)
    add("pad", "box", (W * 0.34, D * 0.28, 0.0006), (0, -D / 2 + 0.018 + D * 0.14, B + 0.0003), rgba=pad,
        collision=False)
    add("hinge", "cylinder", (B * 0.45, W * 0.7), (0, D / 2 - B * 0.4, B * 0.8), rpy=(0, np.pi / 2, 0),
        rgba=bezel, collision=False)
    base_inertial = urdf_inertial(BASE_MASS, (0, 0, B / 2), box_inertia(BASE_MASS, (W, D, B)))

    lparts: list[str] = []

    def ladd(name: str, *a: Any, **k: Any) -> None:
        lparts.append(urdf_part(*a, material=name, **k))

    ladd("shell", "box", (W, D, T), (0, -D / 2, T / 2), rgba=shell)
    # inner face: a black bezel with the screen, 0.5 mm below the lid's inner face (visual only)
    ladd("bezel", "box", (W - 0.004, D - 0.004, 0.0006), (0, -D / 2, -0.0003), rgba=bezel, collision=False)
    ladd("screen", "box", (W - 0.03, D - 0.035, 0.0008), (0, -D / 2 - 0.003, -0.0005), rgba=screen,
         collision=False)
    # outer face: a logo in the middle
    ladd("logo", "cylinder", (0.022, 0.0008), (0, -D / 2, T + 0.0004), rgba=logo, collision=False)
    lid_inertial = urdf_inertial(LID_MASS, (0, -D / 2, T / 2), box_inertia(LID_MASS, (W, D, T)))
    hx, hy, hz = laptop_geometry(v)["hinge_base"]
    nl = "\n    "
    return f"""<?xml version="1.0"?>
<robot name="laptop">
  <link name="base">
    {base_inertial}
    {nl.join(parts)}
  </link>
  <link name="lid">
    {lid_inertial}
    {nl.join(lparts)}
  </link>
  <joint name="lid_hinge" type="revolute">
    <parent link="base"/>
    <child link="lid"/>
    <origin xyz="{hx:.6g} {hy:.6g} {hz:.6g}" rpy="0 0 0"/>
    <axis xyz="-1 0 0"/>
    <limit lower="0" upper="{LID_UPPER}" effort="100" velocity="10"/>
    <dynamics damping="{HINGE_DAMPING}" friction="{HINGE_FRICTION}"/>
  </joint>
</robot>
"""
