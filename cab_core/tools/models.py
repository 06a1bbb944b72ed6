"""What the tools' pydantic models share: the vocabularies and numeric types of their fields, the
bases :class:`Args` and :class:`Result`, and the observation summary several tools return.

Each tool's own argument and result models sit beside its handler (``observe``, ``estimate``,
``motion``; ``run_code``'s and ``done``'s beside their declarations in :mod:`cab_core.tools`).
The JSON Schemas generated from them are what a model reads, so every field says its units and
frame. Conventions shared by all tools (FACTS §A.4):

- one right-handed world frame in metres: +x robot-right, +y forward (away from the robot), +z up;
- poses ``[x, y, z, qw, qx, qy, qz]``, quaternions wxyz;
- gripper-local axes: +x approach (wrist toward fingertips), +y finger-opening line, +z completes;
- pixels ``[u, v]`` in the observation's own image: top-left origin, zero-based, u right, v down.

Argument models forbid extra fields. Cross-field rules (mutually exclusive references,
orthogonal axes, equal-length lists) are ``model_validator``s whose messages say how to fix the
call. Result models document payloads; they allow extra keys so handlers can add diagnostics.
"""
from __future__ import annotations

import math
from typing import Annotated, Any, Literal, get_args

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, Strict

# -- shared vocabularies ------------------------------------------------------------------------
Arm = Literal["left", "right"]
CameraName = Literal["head_camera", "left_camera", "right_camera"]
WristCamera = Literal["left_camera", "right_camera"]
EvidenceView = Literal["overview", "left_wrist", "right_wrist"]
CAMERAS: tuple[str, ...] = get_args(CameraName)  # head_camera, left_camera, right_camera

WORKSPACE = {"x": (-0.8, 0.8), "y": (-0.8, 0.8), "z": (0.4, 1.5)}  # FACTS §A.5 envelope, metres
CONTACT_IMPULSE_THRESHOLD = 1e-4  # N*s, sensor floor of finger contact (FACTS §A.5)

# Declared ranges of every numeric argument (the schema shows them as minimum/maximum). They are far
# wider than any useful value, so they refuse only nonsense (1e308, overflow), never a real request.
COORD_LIMIT_M = 10.0  # world coordinates of points, metres (the table scene spans about 1.6 m)
DELTA_LIMIT_M = 10.0  # components of displacements, metres (motion tools clamp the norm to 0.30 m)
PIXEL_LIMIT_PX = 10_000.0  # pixel coordinates: points well outside the image are still meaningful
AXIS_LIMIT = 1_000.0  # components of directions and quaternions, which are normalised internally


def _norm(v: list[float]) -> float:
    return math.sqrt(sum(x * x for x in v))


def _nonzero_vector(v: list[float]) -> list[float]:
    n = _norm(v)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("must be a non-zero vector")
    return v


def _unit_quaternion(q: list[float]) -> list[float]:
    n = _norm(q)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("quaternion must be non-zero (order w, x, y, z)")
    return [x / n for x in q]


def bounded(lo: float, hi: float, *, lo_open: bool = False) -> Any:
    """The metadata of a number field, ``Annotated[float, bounded(lo, hi)]``: a finite number within
    [lo, hi] (or (lo, hi] with ``lo_open``); a JSON integer is accepted, a string, a boolean or null
    is refused (strict, never coerced)."""
    if lo_open:
        return Field(strict=True, allow_inf_nan=False, gt=lo, le=hi)
    return Field(strict=True, allow_inf_nan=False, ge=lo, le=hi)


Coord = Annotated[float, bounded(-COORD_LIMIT_M, COORD_LIMIT_M)]
Delta = Annotated[float, bounded(-DELTA_LIMIT_M, DELTA_LIMIT_M)]
PixelCoord = Annotated[float, bounded(-PIXEL_LIMIT_PX, PIXEL_LIMIT_PX)]
AxisComponent = Annotated[float, bounded(-AXIS_LIMIT, AXIS_LIMIT)]

Vec3 = Annotated[list[Coord], Field(min_length=3, max_length=3)]
Delta3 = Annotated[list[Delta], Field(min_length=3, max_length=3)]
Direction3 = Annotated[list[AxisComponent], Field(min_length=3, max_length=3), AfterValidator(_nonzero_vector)]
QuatWXYZ = Annotated[list[AxisComponent], Field(min_length=4, max_length=4), AfterValidator(_unit_quaternion)]
Pixel = Annotated[list[PixelCoord], Field(min_length=2, max_length=2)]
ObsId = Annotated[str, Strict(), Field(min_length=1, max_length=64)]


class Args(BaseModel):
    """Base of every argument model: unknown fields are errors."""
    model_config = ConfigDict(extra="forbid")


# -- result models (documentation of payloads) ---------------------------------------------------
class Result(BaseModel):
    """Base of documented result payloads; handlers may add keys."""
    model_config = ConfigDict(extra="allow")


class CamPoseSnapshot(Result):
    available: bool = Field(description="Calibration was read.")
    K: list[list[float]] = Field(description="3x3 pinhole intrinsics, pixels, no distortion.")
    E: list[list[float]] = Field(description="3x4 world->camera [R|t]: p_cam = R p_world + t.")
    size_hw: list[int] = Field(description="[H, W] of the image, pixels.")
    freshness: str = Field(description="'captured_at_tick': the snapshot matches the image.")
    read_failures: int = Field(description="Calibration read failures.")
    convention: str = Field(description="Camera axes: +x right, +y down, +z forward.")


class ObservationSummary(Result):
    """JSON part of an Observation; the RGB image is attached separately."""
    obs_id: str = Field(description="Identifier to pass to geometry tools.")
    camera: str = Field(description="head_camera, left_camera or right_camera.")
    tick: int = Field(description="Actuation tick at capture.")
    cam_pose_snapshot: CamPoseSnapshot = Field(description="Calibration at capture.")
    image: dict[str, Any] = Field(description="{attached, size_hw}.")
    annotation: dict[str, Any] | None = Field(default=None, description="Tool-specific overlay data.")
    source_obs_id: str | None = Field(default=None, description="For annotated copies: the observation drawn on.")

