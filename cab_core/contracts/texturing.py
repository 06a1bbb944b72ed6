"""Textured primitives (``Material.texture``), written once for every simulator backend.

A backend draws a textured primitive (box, sphere, cylinder, capsule) as the triangle mesh
:func:`uv_mesh` writes: the primitive's own surface (a sphere, cylinder and capsule as 48 segments
round, a sphere and a capsule's caps as 24 rings pole to pole), in the shape's local frame (the
scene description's conventions: cylinder and capsule axes along local x), with texture
coordinates in units of :data:`TILE_M` metres of surface. The image is repeated once every
``TILE_M`` metres along each surface direction, whatever the primitive's size: a 1.2 m table top
shows four tiles across, a 3 m wall ten tiles up. A backend's texture sampler repeats (wraps) the
image beyond 0..1, which every backend's does. Mapping per primitive:

- box: each face on its own, u and v along the face's two edges (top and bottom: u along x, v
  along y; the faces normal to y: x and z; those normal to x: y and z), from the face's corner;
- cylinder: the side unrolled (u along the circumference, v along the axis), each cap projected
  onto its plane (u along y, v along z);
- sphere: longitude and latitude measured as arc lengths on the surface (u round the equator about
  local z, v from pole to pole), so tiles keep their size at the equator and shrink towards the
  poles;
- capsule: the cylinder's unrolled side continued over both hemispheres (v the arc length along
  the axis and over the caps, u round the axis).

The scale is specified; the image's orientation on a face is what the engine makes of the
coordinates (the backends shipped with the project agree: the conformance panel's diagonal stripes
run the same way in each). Meshes keep their plain colour (their own texture coordinates, if any,
are the file's and not tiled by anyone here); a backend says so where it documents textures.

The image: :func:`texture_image` checks that the file exists and is a readable image, and hands
back a path each backend can load (the file itself when it is an 8-bit RGB PNG, else an RGB PNG
converted from it into the cache folder). Its bytes are display (sRGB) values, like any PNG: a
backend shows them as it shows a plain colour's display value. Nothing here imports a simulator.
"""
from __future__ import annotations

import hashlib
import math
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cab_core.contracts.scene import Box, Capsule, Cylinder, Mesh, Sphere, cache_dir
from cab_core.errors import SimulatorError

#: metres of surface one repetition of a texture image covers
TILE_M = 0.3
#: segments round a curved primitive, and rings from pole to pole of a sphere
SEGMENTS = 48
RINGS = 24
_FORMAT = 1  # bump when the meshes written change


def textured(shape) -> bool:
    """Whether a visual shape is drawn textured: a texture is set and its geometry a primitive."""
    return shape.material.texture is not None and not isinstance(shape.geometry, Mesh)


def texture_image(path, what: str) -> str:
    """The texture image ``path`` as a file every backend loads: the file itself when it is an
    8-bit RGB PNG, else an RGB PNG converted from it (alpha dropped) in the cache folder, made once.
    ``SimulatorError`` naming the file (and ``what`` wears it) when it is missing or unreadable."""
    from PIL import Image, UnidentifiedImageError

    p = os.path.abspath(os.fspath(path))
    if not os.path.isfile(p):
        raise SimulatorError(f"{what}: texture file not found: {p}")
    try:
        with Image.open(p) as im:
            im.load()
            if im.format == "PNG" and im.mode == "RGB":
                if im.width < 1 or im.height < 1:
                    raise SimulatorError(f"{what}: texture file {p} is an empty image")
                return p
            rgb = im.convert("RGB")
    except (OSError, UnidentifiedImageError, ValueError) as e:
        raise SimulatorError(f"{what}: texture file {p} is not a readable image ({e})") from None
    st = os.stat(p)
    key = hashlib.sha256(f"{p}:{st.st_size}:{st.st_mtime_ns}".encode()).hexdigest()[:16]
    folder = cache_dir() / "textures" / "rgb"
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{Path(p).stem}-{key}.png"
    if not out.exists():
        tmp = out.with_suffix(f".{os.getpid()}.tmp.png")
        rgb.save(tmp)
        tmp.replace(out)
    return str(out)


def uv_mesh(geometry, tile_m: float = TILE_M) -> str:
    """An OBJ file (positions, texture coordinates, normals; counter-clockwise outward faces) of the
    primitive ``geometry`` in its shape frame, texture coordinates in tiles of ``tile_m`` metres;
    written once into the cache folder. See the module docstring for the mapping."""
    build: Callable[..., tuple]  # the shape's dimensions -> vertices, texture coordinates, normals, triangles
    if isinstance(geometry, Box):
        dims = tuple(float(h) for h in geometry.half_size)
        build = _box
    elif isinstance(geometry, Sphere):
        dims = (float(geometry.radius),)
        build = _sphere
    elif isinstance(geometry, Cylinder):
        dims = (float(geometry.radius), float(geometry.half_length))
        build = _cylinder
    elif isinstance(geometry, Capsule):
        dims = (float(geometry.radius), float(geometry.half_length))
        build = _capsule
    else:
        raise TypeError(f"no textured mesh for {type(geometry).__name__}")
    if not all(math.isfinite(d) and d > 0 for d in dims):
        raise SimulatorError(f"{type(geometry).__name__} {dims}: sizes must be positive")
    key = hashlib.sha256(repr((_FORMAT, build.__name__, dims, float(tile_m), SEGMENTS, RINGS)).encode()
                         ).hexdigest()[:16]
    folder = cache_dir() / "uv-meshes"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{build.__name__.strip('_')}-{key}.obj"
    if not path.exists():
        v, uv, n, tris = build(*dims)
        uv = uv / float(tile_m)
        lines = [f"# cab textured primitive {build.__name__.strip('_')} {dims}, tile {tile_m} m"]
        lines += [f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in v]
        lines += [f"vt {a:.9g} {b:.9g}" for a, b in uv]
        lines += [f"vn {a:.9g} {b:.9g} {c:.9g}" for a, b, c in n]
        lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in t) for t in tris]
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text("\n".join(lines) + "\n")
        tmp.replace(path)
    return str(path)


# -- the primitives: (positions, uv in metres, normals, triangles), one vertex per (position, uv, normal)


def _box(hx: float, hy: float, hz: float):
    h = np.array([hx, hy, hz])
    verts: list = []
    uvs: list = []
    norms: list = []
    tris: list = []
    # (normal axis, sign, u axis, v axis); u x v = the outward normal, so (0,1,2,3) runs anticlockwise
    for axis, sign, ua, va in ((2, 1, 0, 1), (2, -1, 1, 0), (1, -1, 0, 2), (1, 1, 2, 0), (0, 1, 1, 2),
                               (0, -1, 2, 1)):
        base = len(verts)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[axis] = sign * h[axis]
            p[ua] = su * h[ua]
            p[va] = sv * h[va]
            verts.append(p)
            uvs.append((p[ua] + h[ua], p[va] + h[va]))
            nn = np.zeros(3)
            nn[axis] = sign
            norms.append(nn)
        tris += [(base, base + 1, base + 2), (base, base + 2, base + 3)]
    return np.array(verts), np.array(uvs), np.array(norms), tris


def _grid(pos, nrm, uv, rows: int, cols: int, tris: list, verts: list, uvs: list, norms: list) -> None:
    """A (rows+1) x (cols+1) vertex grid given as functions of (i, j); quads split in two,
    wound anticlockwise seen from outside when i runs along +u and j along +v."""
    base = len(verts)
    for i in range(rows + 1):
        for j in range(cols + 1):
            verts.append(pos(i, j))
            norms.append(nrm(i, j))
            uvs.append(uv(i, j))
    w = cols + 1
    for i in range(rows):
        for j in range(cols):
            a, b, c, d = base + i * w + j, base + (i + 1) * w + j, base + (i + 1) * w + j + 1, base + i * w + j + 1
            tris += [(a, b, c), (a, c, d)]


def _ring(t: float) -> tuple[float, float]:
    a = 2 * math.pi * t
    return math.cos(a), math.sin(a)


def _side(r: float, x0: float, x1: float, verts, uvs, norms, tris) -> None:
    """The side of a cylinder along x from x0 to x1: u round the axis, v along it."""
    def pos(i, j):
        c, s = _ring(i / SEGMENTS)
        return np.array([x0 + (x1 - x0) * j, r * c, r * s])

    def nrm(i, j):
        c, s = _ring(i / SEGMENTS)
        return np.array([0.0, c, s])

    # i along +u (round the axis, +y towards +z), j along +x: (round) x (+x) points outward
    _grid(pos, nrm, lambda i, j: (2 * math.pi * r * i / SEGMENTS, x0 + (x1 - x0) * j), SEGMENTS, 1, tris,
          verts, uvs, norms)


def _cylinder(r: float, h: float):
    verts: list = []
    uvs: list = []
    norms: list = []
    tris: list = []
    _side(r, -h, h, verts, uvs, norms, tris)
    for sign in (1, -1):  # caps: a fan round the centre, projected onto (y, z)
        centre = len(verts)
        verts.append(np.array([sign * h, 0.0, 0.0]))
        norms.append(np.array([sign, 0.0, 0.0]))
        uvs.append((r, r))
        for i in range(SEGMENTS + 1):
            c, s = _ring(i / SEGMENTS)
            verts.append(np.array([sign * h, r * c, r * s]))
            norms.append(np.array([sign, 0.0, 0.0]))
            uvs.append((r + r * c, r + r * s))
        for i in range(SEGMENTS):
            a, b = centre + 1 + i, centre + 2 + i
            tris.append((centre, a, b) if sign > 0 else (centre, b, a))
    return np.array(verts), np.array(uvs), np.array(norms), tris


def _sphere(r: float):
    verts: list = []
    uvs: list = []
    norms: list = []
    tris: list = []

    def unit(i, j):  # i round z (longitude), j from the south pole (-z) to the north pole
        lat = -math.pi / 2 + math.pi * j / RINGS
        c, s = _ring(i / SEGMENTS)
        return np.array([math.cos(lat) * c, math.cos(lat) * s, math.sin(lat)])

    # i along +u (anticlockwise about +z), j along +v (towards +z): u x v is outward
    _grid(lambda i, j: r * unit(i, j), unit,
          lambda i, j: (2 * math.pi * r * i / SEGMENTS, math.pi * r * j / RINGS), SEGMENTS, RINGS, tris,
          verts, uvs, norms)
    return np.array(verts), np.array(uvs), np.array(norms), tris


def _capsule(r: float, h: float):
    verts: list = []
    uvs: list = []
    norms: list = []
    tris: list = []
    quarter = math.pi * r / 2  # arc length of a cap, pole to rim
    half_rings = max(2, RINGS // 2)

    def cap(sign: int) -> None:
        def unit(i, j):  # j = 0 at the rim, half_rings at the pole
            lat = math.pi / 2 * j / half_rings
            c, s = _ring(i / SEGMENTS)
            return np.array([sign * math.sin(lat), math.cos(lat) * c, math.cos(lat) * s])

        def pos(i, j):
            p = r * unit(i, j)
            p[0] += sign * h
            return p

        def uv(i, j):
            return (2 * math.pi * r * i / SEGMENTS, quarter + h + sign * (h + quarter * j / half_rings))

        n0 = len(tris)
        _grid(pos, unit, uv, SEGMENTS, half_rings, tris, verts, uvs, norms)
        if sign < 0:  # (round) x (towards the -x pole) points inward: flip
            tris[n0:] = [(a, c, b) for a, b, c in tris[n0:]]

    _side(r, -h, h, verts, uvs, norms, tris)
    k = len(uvs) - 2 * (SEGMENTS + 1)
    uvs[k:] = [(u, v + quarter + h) for u, v in uvs[k:]]  # the side's v continues from the -x cap
    cap(1)
    cap(-1)
    return np.array(verts), np.array(uvs), np.array(norms), tris
