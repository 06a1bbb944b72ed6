"""SAPIEN's start-up: the BRDF table SAPIEN would generate in every process (5-19 s on lavapipe) is
read from the cache folder, and Mesa's shader cache lives there too. Images are identical with
SAPIEN's own table, a cold cache and a warm one; the stored table is what the cameras use; a stale
or damaged file is never used."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("sapien")

from cab_sim_sapien import brdf  # noqa: E402

pytestmark = pytest.mark.sim
HERE = Path(__file__).parent
TASKS = ["click_bell", "open_microwave"]


def _render(tmp: Path, cache: Path, name: str, **options) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "MESA_SHADER_CACHE_DIR"}
    env["CAB_CACHE_DIR"] = str(cache)
    out = tmp / f"{name}.npz"
    subprocess.run([sys.executable, str(HERE / "sapien_images.py"), json.dumps(options), str(out), *TASKS],
                   env=env, check=True, capture_output=True, timeout=600)
    with np.load(out) as z:
        return {k: z[k] for k in z.files}


def _environment(tmp: Path) -> list[str]:
    """Six faces of a bright, coloured environment map: specular light for the table to weigh."""
    from PIL import Image

    faces = []
    for i, rgb in enumerate([(255, 230, 200), (90, 160, 255), (255, 255, 255), (40, 40, 40),
                             (200, 255, 160), (255, 120, 120)]):
        faces.append(str(tmp / f"face{i}.png"))
        Image.new("RGB", (16, 16), rgb).save(faces[-1])
    return faces


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("brdf")
    cache = tmp / "cache"
    env = _environment(tmp)
    out = {"sapien": _render(tmp, tmp / "unused", "sapien", brdf_cache=False, env_faces=env),
           "cold": _render(tmp, cache, "cold", env_faces=env),
           "warm": _render(tmp, cache, "warm", env_faces=env)}
    return out, cache, tmp, env


def test_images_identical_with_sapien_table_cold_and_warm_cache(renders):
    out, cache, _, _ = renders
    assert list(out["sapien"]["sources"]) == ["sapien", "sapien"]
    assert out["cold"]["sources"][0].startswith("generated (") and out["cold"]["sources"][1].startswith("generated (")
    assert list(out["warm"]["sources"]) == ["cache", "cache"]
    keys = [k for k in out["sapien"] if k != "sources"]
    assert len(keys) == 3 * len(TASKS)
    for k in keys:
        assert out["sapien"][k].std() > 10  # a real picture, not a blank frame
        assert np.array_equal(out["sapien"][k], out["cold"][k]), k
        assert np.array_equal(out["cold"][k], out["warm"][k]), k
    tables = list((cache / "sapien").glob("brdf-lut-*.npz"))
    assert len(tables) == 1
    assert any((cache / "mesa").rglob("*")), "Mesa's shader cache was not written under the cache folder"


def test_the_stored_table_is_the_one_the_cameras_use(renders):
    out, cache, tmp, env = renders
    [path] = (cache / "sapien").glob("brdf-lut-*.npz")
    with np.load(path) as z:
        lut, key = z["lut"], str(z["key"])
    doctored = tmp / "doctored"
    (doctored / "sapien").mkdir(parents=True)
    with open(doctored / "sapien" / path.name, "wb") as f:  # same key, a darker table
        np.savez(f, lut=(lut * np.float16(0.25)).astype(np.float16), key=np.array(key))
    dark = _render(tmp, doctored, "dark", env_faces=env)
    assert list(dark["sources"]) == ["cache", "cache"]
    changed = [k for k in out["warm"] if k != "sources" and not np.array_equal(out["warm"][k], dark[k])]
    assert len(changed) == 3 * len(TASKS)


def _write(path: Path, lut, key) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        np.savez(f, lut=lut, key=np.array(key))


def test_a_stale_or_damaged_table_is_never_used(tmp_path, monkeypatch):
    monkeypatch.setenv("CAB_CACHE_DIR", str(tmp_path))
    key = brdf.cache_key("llvmpipe (LLVM 15.0.6, 256 bits)")
    path = brdf.cache_path(key)
    assert path.parent == tmp_path / "sapien"
    good = np.full((brdf.LUT_SIZE, brdf.LUT_SIZE, 2), 0.5, np.float16)
    _write(path, good, key)
    assert np.array_equal(brdf._load(path, key), good)
    assert brdf._load(path, key.replace("sapien ", "sapien 0")) is None  # another SAPIEN's table
    assert brdf.cache_path(brdf.cache_key("NVIDIA RTX 4090")) != path  # another device: another file
    _write(path, good[:256], key)
    assert brdf._load(path, key) is None  # wrong shape
    _write(path, good.astype(np.float32), key)
    assert brdf._load(path, key) is None  # wrong precision
    bad = good.copy()
    bad[3, 3, 0] = np.inf
    _write(path, bad, key)
    assert brdf._load(path, key) is None
    path.write_bytes(path.read_bytes()[:1000])  # torn write
    assert brdf._load(path, key) is None
    path.unlink()
    assert brdf._load(path, key) is None


def test_shader_packs_that_sample_the_table(tmp_path):
    import sapien

    shipped = Path(sapien.__file__).parent / "vulkan_shader"
    assert brdf.uses_lut(str(shipped / "default"))
    assert brdf.uses_lut(str(shipped / "minimal"))  # its forward pass lights with it too
    assert not brdf.uses_lut(str(shipped / "trivial"))
