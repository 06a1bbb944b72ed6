"""cab_core.contracts.texturing: the textured primitives' meshes and the image check every
simulator backend shares (the backends themselves: the conformance check ``textures``)."""
import math

import numpy as np
import pytest
from PIL import Image

from cab_core.attempt.variation.randomize import pattern_texture
from cab_core.contracts import texturing
from cab_core.contracts.scene import Box, Capsule, Cylinder, Material, Mesh, Shape, Sphere
from cab_core.errors import SimulatorError


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CAB_CACHE_DIR", str(tmp_path / "cache"))


def _read_obj(path):
    v, vt, vn, faces = [], [], [], []
    for line in open(path):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        if parts[0] == "v":
            v.append([float(x) for x in parts[1:]])
        elif parts[0] == "vt":
            vt.append([float(x) for x in parts[1:]])
        elif parts[0] == "vn":
            vn.append([float(x) for x in parts[1:]])
        elif parts[0] == "f":
            faces.append([[int(i) - 1 for i in c.split("/")] for c in parts[1:]])
    return np.array(v), np.array(vt), np.array(vn), faces


@pytest.mark.parametrize("geometry, volume", [
    (Box((0.6, 0.35, 0.025)), 8 * 0.6 * 0.35 * 0.025),
    (Sphere(0.1), 4 / 3 * math.pi * 0.1 ** 3),
    (Cylinder(0.05, 0.2), math.pi * 0.05 ** 2 * 0.4),
    (Capsule(0.05, 0.2), math.pi * 0.05 ** 2 * 0.4 + 4 / 3 * math.pi * 0.05 ** 3),
])
def test_uv_mesh_is_the_closed_outward_primitive(geometry, volume):
    path = texturing.uv_mesh(geometry)
    assert texturing.uv_mesh(geometry) == path  # made once
    v, vt, vn, faces = _read_obj(path)
    signed = 0.0
    for f in faces:
        (a, _, na), (b, _, nb), (c, _, nc) = f
        cross = np.cross(v[b] - v[a], v[c] - v[a])
        if np.linalg.norm(cross) > 1e-12:  # the poles' degenerate triangles aside
            assert np.dot(cross, vn[na] + vn[nb] + vn[nc]) > 0, "a face winds inward"
        signed += np.dot(v[a], np.cross(v[b], v[c])) / 6
    assert signed == pytest.approx(volume, rel=0.02)
    np.testing.assert_allclose(np.linalg.norm(vn, axis=1), 1.0, atol=1e-6)


def test_uv_mesh_tiles_every_face_in_metres():
    """Texture coordinates advance one unit per TILE_M metres along each face's edges."""
    v, vt, _, faces = _read_obj(texturing.uv_mesh(Box((0.6, 0.35, 0.025))))
    for f in faces:
        (a, ta, _), (b, tb, _) = f[0], f[1]
        dist = np.linalg.norm(v[b] - v[a])
        assert np.linalg.norm(vt[tb] - vt[ta]) == pytest.approx(dist / texturing.TILE_M, rel=1e-6)
    # the 1.2 m top shows four tiles across
    assert vt[:, 0].max() == pytest.approx(1.2 / texturing.TILE_M)


def test_cylinder_axis_is_local_x():
    v, *_ = _read_obj(texturing.uv_mesh(Cylinder(0.05, 0.2)))
    np.testing.assert_allclose(v.min(axis=0), [-0.2, -0.05, -0.05], atol=1e-6)
    np.testing.assert_allclose(v.max(axis=0), [0.2, 0.05, 0.05], atol=1e-6)


def test_textured_means_a_primitive_with_an_image():
    img = "/x.png"
    assert texturing.textured(Shape(Box((1, 1, 1)), material=Material(texture=img)))
    assert not texturing.textured(Shape(Box((1, 1, 1))))
    assert not texturing.textured(Shape(Mesh("/m.obj"), material=Material(texture=img)))


def test_texture_image(tmp_path):
    rgb = tmp_path / "rgb.png"
    Image.fromarray(np.full((8, 8, 3), 200, np.uint8)).save(rgb)
    assert texturing.texture_image(rgb, "body 'x'") == str(rgb)
    rgba = tmp_path / "rgba.png"
    Image.fromarray(np.full((8, 8, 4), 100, np.uint8)).save(rgba)
    out = texturing.texture_image(rgba, "body 'x'")
    assert out != str(rgba)
    with Image.open(out) as im:
        assert (im.format, im.mode, im.size) == ("PNG", "RGB", (8, 8))
    with pytest.raises(SimulatorError, match="body 'x': texture file not found: .*missing.png"):
        texturing.texture_image(tmp_path / "missing.png", "body 'x'")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(SimulatorError, match="bad.png is not a readable image"):
        texturing.texture_image(bad, "body 'x'")


def test_pattern_texture_is_srgb_encoded():
    """The light parts of a procedural texture are its colour as an image shows it (sRGB)."""
    rgb = (0.2, 0.5, 0.8)
    with Image.open(pattern_texture("checks", rgb, 7)) as im:
        px = np.asarray(im.convert("RGB"), float).reshape(-1, 3)
    light = px[np.argmax(px.sum(axis=1))]
    want = [255 * (1.055 * c ** (1 / 2.4) - 0.055) for c in rgb]
    np.testing.assert_allclose(light, want, atol=1.0)
