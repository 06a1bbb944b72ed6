"""The physical parameters in which MuJoCo differs from the other backends, declared in one place.

The scene description and the embodiment carry the physics every backend shares (masses, friction
coefficients, drive stiffness and damping). What is left is how MuJoCo's soft-contact solver is set
up to behave like the rigid contacts of PhysX, on which the suite's figures were first measured.
Each default below says what it means and why it has its value; ``conf/sim/mujoco.yaml`` (key
``physics``) overrides any of them by name. Nothing here depends on a task.

Differences that no parameter removes, by MuJoCo's design: one friction coefficient per geom (the
material's dynamic one is used: PhysX's static coefficient only matters at the onset of sliding),
and a pair's friction is the larger of its two geoms' (PhysX averages them).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from cab_core.errors import ConfigError


@dataclass(frozen=True)
class PhysicsParams:
    # integration: implicit in the velocity terms, so the drives' damping (200 N s/m on a 50 g
    # finger) stays stable at the suite's 4 ms step
    integrator: str = "implicitfast"
    # friction cones: elliptic cones with a high impratio make friction nearly as hard as the
    # normal force, so a squeezed object does not creep out of a grasp (PhysX friction is hard)
    cone: str = "elliptic"
    impratio: float = 10.0
    solver_iterations: int = 100
    solver_tolerance: float = 1e-10
    noslip_iterations: int = 0
    # contacts: 3 = sliding friction only; 4 adds torsional friction, which stops a held object
    # from spinning about the grip axis (PhysX's patch friction does that on its own)
    condim: int = 4
    torsional_friction: float = 0.01  # metres (MuJoCo's torsional coefficient)
    rolling_friction: float = 0.0
    # soft-contact stiffness: time constant (s) and damping ratio; solimp (d0, dwidth, width m)
    contact_solref: tuple[float, float] = (0.01, 1.0)
    contact_solimp: tuple[float, float, float] = (0.95, 0.99, 0.001)
    contact_margin: float = 0.0
    # joints of articulated objects: armature (kg m^2, or kg on a slider), for numerical robustness
    joint_armature: float = 0.001
    # robot joints: the servos' damping (200) is integrated implicitly, but MuJoCo's contact solver
    # computes contact forces with the bare link inertia; on light links (a 50 g finger, the wrist)
    # the contacts then come out many times too soft (a squeezed object sinks into the pads and
    # slips out). Armature of the order of timestep x damping (0.8) restores them; tracking barely
    # changes, the servos being overdamped (time constant damping / stiffness = 0.2 s) either way.
    drive_armature: float = 1.0
    # PhysX joint friction is a coefficient; MuJoCo's frictionloss is a torque (N m): the scale
    # that turns a scene's joint_friction into a frictionloss
    joint_friction_scale: float = 1.0
    # MuJoCo's dry friction is soft too: under a load below frictionloss a joint still creeps, at a
    # speed set by this impedance (d0, dmax, width). dmax near 1 makes it hold, as static friction
    # does (a laptop lid stays where it was left)
    joint_friction_solimp: tuple[float, float, float] = (0.99, 0.99999, 0.001)

    @classmethod
    def from_cfg(cls, overrides: dict | None) -> PhysicsParams:
        """The defaults with ``overrides`` applied; unknown names and bad values are ConfigErrors."""
        overrides = dict(overrides or {})
        known = {f.name: f for f in fields(cls)}
        bad = sorted(set(overrides) - set(known))
        if bad:
            raise ConfigError(f"unknown mujoco physics parameter(s) {bad}; known: {sorted(known)}")
        base = cls()
        clean = {}
        for k, v in overrides.items():
            default = getattr(base, k)
            try:
                if isinstance(default, tuple):
                    v = tuple(float(x) for x in v)
                    if len(v) != len(default):
                        raise ValueError(f"expected {len(default)} numbers")
                elif isinstance(default, str):
                    v = str(v)
                else:
                    v = type(default)(v)
            except (TypeError, ValueError) as e:
                raise ConfigError(f"mujoco physics parameter {k}={v!r}: {e}") from None
            clean[k] = v
        p = replace(base, **clean)
        if p.integrator not in ("Euler", "implicit", "implicitfast", "RK4"):
            raise ConfigError(f"mujoco integrator {p.integrator!r} is not one of Euler, implicit, implicitfast, RK4")
        if p.cone not in ("pyramidal", "elliptic"):
            raise ConfigError(f"mujoco cone {p.cone!r} is not pyramidal or elliptic")
        if p.condim not in (1, 3, 4, 6):
            raise ConfigError(f"mujoco condim {p.condim} is not 1, 3, 4 or 6")
        return p

    def as_dict(self) -> dict:
        return asdict(self)
