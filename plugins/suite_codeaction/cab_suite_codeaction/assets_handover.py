"""Generated assets of the handover group (handover_mic, place_mouse_pad, rotate_qrcode): a desk
microphone, a computer mouse, a mouse mat and a QR-code payment sign, all built from primitives and
trimesh meshes by code (nothing is downloaded).

Every builder returns the body's shapes in its own frame plus the privileged points the verifier,
the oracle and the checkpoints use (functional points, grasp points), so that a task module only
places the body.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from cab_core.contracts.scene import Box, Cylinder, Mesh, Shape, Sphere
from cab_core.kits.assets import mesh_asset
from cab_core.kits.scene import material

# local x -> z: a SAPIEN cylinder/capsule (axis along local x) standing upright
X_TO_Z = (float(np.sqrt(0.5)), 0.0, -float(np.sqrt(0.5)), 0.0)


_mat = partial(material, roughness=0.5)  # this module's default finish


# ---------------------------------------------------------------------------------------------
# microphone (handover_mic): a handheld microphone in a small round desk stand
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MicVariant:
    """Upstream ``018_microphone`` ids {0, 4, 5} become three colourings/sizes of one design."""
    handle_r: float
    handle_len: float
    head_r: float
    base_r: float
    handle_rgb: tuple[float, float, float]
    head_rgb: tuple[float, float, float]
    base_rgb: tuple[float, float, float]
    mass: float


MIC_VARIANTS: dict[int, MicVariant] = {
    0: MicVariant(0.0150, 0.120, 0.0240, 0.036, (0.08, 0.08, 0.09), (0.72, 0.73, 0.75), (0.20, 0.20, 0.22), 0.22),
    4: MicVariant(0.0145, 0.125, 0.0235, 0.035, (0.70, 0.71, 0.73), (0.10, 0.10, 0.11), (0.12, 0.12, 0.13), 0.24),
    5: MicVariant(0.0155, 0.115, 0.0250, 0.037, (0.92, 0.92, 0.90), (0.25, 0.26, 0.28), (0.85, 0.85, 0.83), 0.20),
}
MIC_BASE_H = 0.012
MIC_COLLAR_H = 0.010
MIC_HEAD_H = 0.030  # cylindrical part of the grille; a dome of the head radius caps it
MIC_FRICTION = 0.9  # rubberised handle and grille mesh


def microphone(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """A desk microphone standing upright: a flat round stand, a handle, a collar and a grille head
    (a short cylinder with a domed top). Frame: origin at the bottom centre of the stand (on the
    table), +z up along the handle; round, so x/y are arbitrary. Returns shapes and facts:
    ``head_point`` (functional point 0: centre of the grille head), ``handle_point`` (middle of
    the handle), ``head_grasp_point`` (where a top-down TCP holds the head), heights and radii."""
    v = MIC_VARIANTS[model_id]
    handle = _mat(v.handle_rgb, roughness=0.45, friction=MIC_FRICTION)
    head = _mat(v.head_rgb, roughness=0.35, metallic=0.6, friction=MIC_FRICTION)
    base = _mat(v.base_rgb, roughness=0.6, friction=0.8)
    z0 = MIC_BASE_H
    z1 = z0 + v.handle_len
    z2 = z1 + MIC_COLLAR_H
    z3 = z2 + MIC_HEAD_H
    shapes = [
        Shape(Cylinder(v.base_r, MIC_BASE_H / 2), pose=(0.0, 0.0, MIC_BASE_H / 2, *X_TO_Z), material=base),
        Shape(Cylinder(v.handle_r, v.handle_len / 2), pose=(0.0, 0.0, (z0 + z1) / 2, *X_TO_Z), material=handle),
        Shape(Cylinder(v.handle_r + 0.004, MIC_COLLAR_H / 2), pose=(0.0, 0.0, (z1 + z2) / 2, *X_TO_Z),
              material=handle),
        Shape(Cylinder(v.head_r, MIC_HEAD_H / 2), pose=(0.0, 0.0, (z2 + z3) / 2, *X_TO_Z), material=head),
        Shape(Sphere(v.head_r), pose=(0.0, 0.0, z3, 1.0, 0.0, 0.0, 0.0), material=head),
        # a thin dark band where the grille meets the collar (visual only)
        Shape(Cylinder(v.head_r + 0.0005, 0.002), pose=(0.0, 0.0, z2 + 0.002, *X_TO_Z),
              material=_mat((0.05, 0.05, 0.05)), collision=False),
    ]
    top = z3 + v.head_r
    facts = {
        "model_id": model_id,
        "mass_kg": v.mass,
        "height": round(top, 6),
        "base_radius": v.base_r,
        "handle_radius": v.handle_r,
        "handle_z_range": [round(z0, 6), round(z1, 6)],
        "head_radius": v.head_r,
        "head_z_range": [round(z2, 6), round(top, 6)],
        "head_point": [0.0, 0.0, round((z2 + top) / 2, 6)],  # functional point 0
        "handle_point": [0.0, 0.0, round(z0 + 0.5 * v.handle_len, 6)],
        "head_grasp_point": [0.0, 0.0, round(top - 0.02, 6)],  # top-down TCP: fingertips 1.5 cm above the collar
    }
    return shapes, facts


# ---------------------------------------------------------------------------------------------
# computer mouse and mouse mat (place_mouse_pad)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MouseVariant:
    """Upstream ``047_mouse`` ids {0, 1, 2} become three sizes/colourings of one design."""
    length: float  # y
    width: float  # x
    height: float  # z
    shell_rgb: tuple[float, float, float]
    detail_rgb: tuple[float, float, float]


MOUSE_VARIANTS: dict[int, MouseVariant] = {
    0: MouseVariant(0.110, 0.062, 0.036, (0.10, 0.10, 0.11), (0.55, 0.56, 0.58)),
    1: MouseVariant(0.105, 0.060, 0.034, (0.93, 0.93, 0.92), (0.30, 0.30, 0.32)),
    2: MouseVariant(0.100, 0.058, 0.033, (0.35, 0.40, 0.50), (0.75, 0.76, 0.78)),
}
MOUSE_MASS = 0.05  # kg (FACTS B.6)
MOUSE_FRICTION = 0.7  # matte plastic shell


def _mouse_half_width(v: MouseVariant, t: np.ndarray) -> np.ndarray:
    """Half-width of the footprint at t = y / (length / 2) in [-1, 1] (back at -1, front at +1):
    widest behind the middle, rounded at both ends."""
    base = 0.5 * v.width * (1.0 - 0.12 * (t + 0.25) ** 2)
    return base * np.sqrt(np.clip(1.0 - np.abs(t) ** 3.5, 0.0, 1.0))


def _mouse_top(v: MouseVariant, x: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Height of the shell over the table: a hump highest a third of the way from the back,
    falling off to the sides and toward the front."""
    hw = np.maximum(_mouse_half_width(v, t), 1e-6)
    across = np.sqrt(np.clip(1.0 - (x / hw) ** 2, 0.0, 1.0))
    along = np.clip(1.0 - 0.55 * (t + 0.3) ** 2, 0.15, 1.0)
    return 0.004 + (v.height - 0.004) * across ** 0.6 * along


def mouse_mesh(v: MouseVariant):
    """The shell as a closed convex mesh (trimesh): a flat bottom and the hump surface, sampled on
    a grid over the footprint and wrapped in their convex hull (a mouse is near-convex)."""
    import trimesh

    pts = []
    for t in np.linspace(-1.0, 1.0, 15):
        hw = float(_mouse_half_width(v, np.array(t)))
        for s in np.linspace(-1.0, 1.0, 9):
            x = s * hw * 0.999
            y = t * v.length / 2
            pts.append((x, y, 0.0))
            pts.append((x, y, float(_mouse_top(v, np.array(x), np.array(t)))))
    hull = trimesh.convex.convex_hull(np.asarray(pts))
    hull.merge_vertices()
    return hull


def mouse_surface_z(model_id: int, x: float, y: float) -> float:
    v = MOUSE_VARIANTS[model_id]
    return float(_mouse_top(v, np.array(x), np.array(2.0 * y / v.length)))


def computer_mouse(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """A computer mouse. Frame: origin at the centre of its footprint on the table, +y toward its
    front (the buttons), +z up. Collision: the shell's convex hull. Visual: the shell, the line
    between the two buttons, a scroll wheel and a thumb-side strip."""
    v = MOUSE_VARIANTS[model_id]
    shell = _mat(v.shell_rgb, roughness=0.4, friction=MOUSE_FRICTION)
    detail = _mat(v.detail_rgb, roughness=0.5)
    dark = _mat((0.03, 0.03, 0.03), roughness=0.6)
    mesh = mouse_mesh(v)
    path = mesh_asset(f"mouse{model_id}", mesh)
    shapes = [Shape(Mesh(path, convex=True), material=shell)]
    # buttons: the split line from the front edge back to the wheel, following the shell's crown
    y_front, y_wheel = 0.46 * v.length, 0.16 * v.length
    for y in np.linspace(y_wheel - 0.004, y_front - 0.004, 6):
        z = mouse_surface_z(model_id, 0.0, float(y))
        seg = (y_front - y_wheel) / 10 + 0.001
        shapes.append(Shape(Box((0.0007, seg, 0.0008)), pose=(0.0, float(y), z, 1.0, 0.0, 0.0, 0.0),
                            material=dark, collision=False))
    zw = mouse_surface_z(model_id, 0.0, 0.5 * (y_wheel + y_front) - 0.01)
    shapes.append(Shape(Cylinder(0.0065, 0.0035), pose=(0.0, 0.5 * (y_wheel + y_front) - 0.01, zw - 0.002,
                                                        1.0, 0.0, 0.0, 0.0), material=detail, collision=False))
    # thumb-side grip strip on the left flank
    yb = -0.05 * v.length
    hw = float(_mouse_half_width(v, np.array(2 * yb / v.length)))
    shapes.append(Shape(Box((0.0015, 0.22 * v.length, 0.006)), pose=(-hw + 0.0008, yb, 0.012, 1.0, 0.0, 0.0, 0.0),
                        material=detail, collision=False))
    facts = {
        "model_id": model_id,
        "mass_kg": MOUSE_MASS,
        "size": [v.width, v.length, v.height],
        "long_axis": [0.0, 1.0, 0.0],
        "grasp_point": [0.0, 0.0, 0.0],  # footprint centre: grasp across the width here
        "grasp_width": round(2 * float(_mouse_half_width(v, np.array(0.0))), 6),
    }
    return shapes, facts


#: the eight mat colours (display sRGB)
MAT_COLOURS: dict[str, tuple[float, float, float]] = {
    "red": (0.80, 0.12, 0.12), "green": (0.12, 0.62, 0.20), "blue": (0.12, 0.30, 0.85),
    "yellow": (0.95, 0.82, 0.10), "purple": (0.50, 0.20, 0.70), "orange": (0.95, 0.50, 0.10),
    "pink": (0.95, 0.50, 0.70), "cyan": (0.10, 0.75, 0.85),
}
MAT_HALF = (0.035, 0.065, 0.0005)


def mouse_mat(colour: str) -> list[Shape]:
    """A thin coloured mat (FACTS B.6: a static box of half-size (0.035, 0.065, 0.0005))."""
    return [Shape(Box(MAT_HALF), material=_mat(MAT_COLOURS[colour], roughness=0.8, friction=0.8))]


# ---------------------------------------------------------------------------------------------
# QR-code payment board (rotate_qrcode)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class QrBoardVariant:
    """Upstream ``070_paymentsign`` ids 0-3 become four payment boards: header colour and the
    encoded text differ."""
    text: str
    header_rgb: tuple[float, float, float]


QR_VARIANTS: dict[int, QrBoardVariant] = {
    0: QrBoardVariant("CABPAY:SHOP-0", (0.13, 0.65, 0.30)),
    1: QrBoardVariant("CABPAY:SHOP-1", (0.10, 0.45, 0.90)),
    2: QrBoardVariant("CABPAY:SHOP-2", (0.85, 0.15, 0.15)),
    3: QrBoardVariant("CABPAY:SHOP-3", (0.95, 0.55, 0.10)),
}
QR_BOARD_HALF = (0.035, 0.050, 0.007)  # 7 x 10 cm, 1.4 cm thick (an acrylic plaque)
QR_BOARD_MASS = 0.12  # kg: acrylic, 1.18 g/cm^3
QR_BOARD_FRICTION = 0.7
QR_SIDE = 0.066  # the code's square incl. its quiet zone
QR_CENTRE_Y = -0.013  # the code sits in the lower part; the coloured header band is at +y
QR_HEADER_Y = (0.024, 0.047)
QR_INK = 0.0004  # printed modules: 0.4 mm proud of the face


def qr_matrix(text: str) -> list[list[bool]]:
    """The QR code of ``text`` (``qrcode`` package, error correction M, no border): rows top to
    bottom, columns left to right, True = dark module."""
    import qrcode

    qr = qrcode.QRCode(error_correction=qrcode.constants.ERROR_CORRECT_M, border=0)
    qr.add_data(text)
    qr.make(fit=True)
    return [[bool(v) for v in row] for row in qr.get_matrix()]


def qr_modules_mesh(matrix: list[list[bool]], side: float, z: float, centre_y: float):
    """The dark modules as thin boxes (runs along a row merged), one trimesh: the code reads
    upright with its top toward +y and its left toward -x; ``side`` includes a 2-module quiet zone
    on each side."""
    import trimesh

    n = len(matrix)
    m = side / (n + 4)
    boxes = []
    for r, row in enumerate(matrix):
        c = 0
        while c < n:
            if not row[c]:
                c += 1
                continue
            c0 = c
            while c < n and row[c]:
                c += 1
            x0 = (c0 - n / 2) * m
            x1 = (c - n / 2) * m
            y = centre_y + (n / 2 - r - 0.5) * m
            t = np.eye(4)
            t[:3, 3] = ((x0 + x1) / 2, y, z + QR_INK / 2)
            boxes.append(trimesh.creation.box(extents=(x1 - x0, m, QR_INK), transform=t))
    return trimesh.util.concatenate(boxes), m


def qr_board(model_id: int) -> tuple[list[Shape], dict[str, Any]]:
    """A rigid QR-code payment board lying flat: a white plaque with a real, scannable QR code of
    ``QR_VARIANTS[id].text`` printed on its top face (black modules, built as thin boxes) and a
    coloured header band with white 'lettering' above the code. Frame: origin at the plaque's
    centre, +z out of the printed face, +y toward the header (the top of the code), +x to the
    code's right. Collision: the plaque (a box)."""
    v = QR_VARIANTS[model_id]
    hx, hy, hz = QR_BOARD_HALF
    white = _mat((0.96, 0.96, 0.95), roughness=0.3, friction=QR_BOARD_FRICTION)
    ink = _mat((0.02, 0.02, 0.02), roughness=0.6)
    header = _mat(v.header_rgb, roughness=0.4)
    matrix = qr_matrix(v.text)
    mesh, module = qr_modules_mesh(matrix, QR_SIDE, hz, QR_CENTRE_Y)
    path = mesh_asset(f"qrcode{model_id}", mesh)
    hy0, hy1 = QR_HEADER_Y
    shapes = [
        Shape(Box(QR_BOARD_HALF), material=white),
        Shape(Mesh(path, convex=False), material=ink, collision=False),
        Shape(Box((hx - 0.003, (hy1 - hy0) / 2, QR_INK / 2)), pose=(0.0, (hy0 + hy1) / 2, hz + QR_INK / 2, 1, 0, 0, 0),
              material=header, collision=False),
    ]
    # 'SCAN TO PAY' as white bars on the header (a pictogram of lettering) and a white logo square
    for i, w in enumerate((0.006, 0.004, 0.007, 0.005, 0.006)):
        x = -0.016 + 0.011 * i
        shapes.append(Shape(Box((w / 2, 0.0025, QR_INK / 2)), pose=(x + 0.006, (hy0 + hy1) / 2 - 0.004, hz + QR_INK, 1, 0, 0, 0),
                            material=white, collision=False))
    shapes.append(Shape(Box((0.004, 0.004, QR_INK / 2)), pose=(-0.024, (hy0 + hy1) / 2 + 0.002, hz + QR_INK, 1, 0, 0, 0),
                        material=white, collision=False))
    facts = {
        "model_id": model_id,
        "mass_kg": QR_BOARD_MASS,
        "half_size": [hx, hy, hz],
        "qr_text": v.text,
        "qr_modules": len(matrix),
        "qr_module_size": round(module, 6),
        "qr_centre": [0.0, QR_CENTRE_Y, hz],
        "face_normal": [0.0, 0.0, 1.0],
        "code_up": [0.0, 1.0, 0.0],
        "grasp_point": [0.0, 0.0, 0.0],  # grasp across the 7 cm width at the centre
        "grasp_width": 2 * hx,
    }
    return shapes, facts
