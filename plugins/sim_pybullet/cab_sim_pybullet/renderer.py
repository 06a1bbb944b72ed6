"""Rendering for the PyBullet backend: which renderer, camera matrices, lighting.

PyBullet renders a DIRECT client with its built-in TinyRenderer, a software rasteriser on the CPU;
with a GPU present it can load the EGL renderer plugin (hardware OpenGL, no display needed). The
choice is made once per simulator by :func:`choose`:

- ``renderer: tiny``  TinyRenderer (any machine).
- ``renderer: egl``   the EGL plugin; fails with :class:`RendererUnavailable` when it cannot start.
- ``renderer: auto``  EGL when an NVIDIA device node exists (``/dev/nvidia*``), else TinyRenderer.
  A GPU whose EGL plugin then fails is an error with a diagnosis, never a silent software fallback.

Camera conventions: cab cameras use OpenCV axes (x right, y down, z forward); OpenGL's camera looks
down its -z with +y up. The view matrix is the inverse of the OpenGL camera's world pose; the
projection matrix is built from the pinhole K so that a world point lands on the pixel K predicts.
"""
from __future__ import annotations

import glob
import importlib.util
from dataclasses import dataclass

import numpy as np

from cab_core.contracts.scene import Lighting
from cab_core.errors import ConfigError, RendererUnavailable
from cab_core.geometry import pose_to_mat

RENDERERS = ("auto", "tiny", "egl")
# OpenGL camera axes written in the OpenCV camera frame: x stays, y and z flip
_GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])


def gpu_device_nodes() -> list[str]:
    """NVIDIA device nodes of this machine (empty on a CPU-only machine)."""
    return sorted(glob.glob("/dev/nvidia[0-9]*"))


@dataclass(frozen=True)
class RendererChoice:
    kind: str  # "tiny" | "egl"
    reason: str


def choose(requested: str) -> RendererChoice:
    """Resolve the ``renderer`` option into the renderer to use (see the module docstring)."""
    if requested not in RENDERERS:
        raise ConfigError(f"pybullet renderer must be one of {list(RENDERERS)}, got {requested!r}")
    if requested == "tiny":
        return RendererChoice("tiny", "requested")
    if requested == "egl":
        return RendererChoice("egl", "requested")
    nodes = gpu_device_nodes()
    if nodes:
        return RendererChoice("egl", f"auto: GPU device {nodes[0]}")
    return RendererChoice("tiny", "auto: no GPU device node")


def load_egl(client) -> int:
    """Load PyBullet's EGL renderer plugin into ``client``; its plugin id."""
    spec = importlib.util.find_spec("eglRenderer")
    if spec is None or not spec.origin:
        raise RendererUnavailable("PyBullet's eglRenderer module is missing from this pybullet build; "
                                  "use renderer: tiny (CPU) or reinstall pybullet")
    plugin = client.loadPlugin(spec.origin, "_eglRendererPlugin")
    if plugin < 0:
        raise RendererUnavailable(
            f"PyBullet's EGL renderer plugin ({spec.origin}) did not start: no usable EGL device "
            f"(GPU nodes: {gpu_device_nodes() or 'none'}). Check the NVIDIA driver's EGL library "
            f"(libEGL_nvidia) is installed, or use renderer: tiny (CPU)")
    return plugin


def display_color(rgba) -> list[float]:
    """A linear RGBA colour (cab's convention, SAPIEN's too) encoded as sRGB: TinyRenderer writes
    the shaded colour to the image as it is, where SAPIEN converts its linear result to sRGB."""
    out = []
    for c in list(rgba)[:3]:
        c = min(1.0, max(0.0, float(c)))
        out.append(12.92 * c if c <= 0.0031308 else 1.055 * c ** (1.0 / 2.4) - 0.055)
    return out + [float(list(rgba)[3]) if len(rgba) > 3 else 1.0]


def view_matrix(camera_pose_cv) -> list[float]:
    """PyBullet view matrix (column-major 16 floats) of a camera with an OpenCV-axes world pose."""
    world_from_gl = pose_to_mat(camera_pose_cv) @ _GL_FROM_CV
    view = np.eye(4)  # the rigid inverse: R^T, -R^T t
    view[:3, :3] = world_from_gl[:3, :3].T
    view[:3, 3] = -view[:3, :3] @ world_from_gl[:3, 3]
    return view.T.reshape(-1).tolist()


def projection_matrix(K: np.ndarray, width: int, height: int, near: float, far: float) -> list[float]:
    """OpenGL projection (column-major) that maps camera points to the pixels K gives them."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.array([
        [2.0 * fx / width, 0.0, 1.0 - 2.0 * cx / width, 0.0],
        [0.0, 2.0 * fy / height, 2.0 * cy / height - 1.0, 0.0],
        [0.0, 0.0, -(far + near) / (far - near), -2.0 * far * near / (far - near)],
        [0.0, 0.0, -1.0, 0.0],
    ])
    return P.T.reshape(-1).tolist()


@dataclass(frozen=True)
class Shading:
    """TinyRenderer's single-light model, derived from the scene's lighting."""
    direction: tuple[float, float, float]  # towards the light
    color: tuple[float, float, float]
    ambient: float
    diffuse: float
    specular: float

    @classmethod
    def from_lighting(cls, lighting: Lighting, diffuse: float, specular: float) -> Shading:
        """The first directional light (the direction light travels, negated) and the mean ambient."""
        if lighting.directional:
            travel, color = lighting.directional[0]
            d = -np.asarray(travel, dtype=float)
            d = d / (np.linalg.norm(d) or 1.0)
        else:
            d, color = np.array([0.0, 0.0, 1.0]), (1.0, 1.0, 1.0)
        c = np.clip(np.asarray(color, dtype=float) / max(max(color), 1e-9), 0.0, 1.0)
        return cls(tuple(d.tolist()), tuple(c.tolist()), float(np.mean(lighting.ambient)), diffuse, specular)

    def kwargs(self) -> dict:
        return dict(lightDirection=list(self.direction), lightColor=list(self.color),
                    lightAmbientCoeff=self.ambient, lightDiffuseCoeff=self.diffuse,
                    lightSpecularCoeff=self.specular, shadow=0)
