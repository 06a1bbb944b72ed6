"""Checks every simulator backend passes beyond the conformance suite of
:mod:`cab_core.testing.sim_conformance` (which ``pytest --cab-conformance`` runs on every installed
backend, with and without a renderer): plugin registration, options, the physics-only mode and the
snapshot, contact and shutdown guarantees. tests/test_sim_backends.py runs them on each simulator
the plugin registry serves. What is particular to one backend moved beside its plugin, to
plugins/sim_<backend>/tests/test_sim_<backend>.py (sim_mujoco, sim_pybullet, sim_sapien).

:func:`backend` describes an installed backend (its registry factory, the class it must build,
how to make it render, what its snapshots promise, and its simulator factories ``rendering``, a
simulator that renders, and ``physics_only``, one built with ``render: false``). Each check takes
such a :class:`Backend`; :data:`CHECKS` lists them.
"""
from __future__ import annotations

import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

from cab_core.contracts.scene import SceneSpec
from cab_core.contracts.simulator import Simulator
from cab_core.errors import ConfigError, RendererUnavailable, SimulatorError
from cab_core.plugins import build_plugin_manager, registry
from cab_core.testing import sim_conformance as sc


@dataclass(frozen=True)
class Backend:
    name: str
    make: Callable[[dict], Simulator]  # the registry's factory: options -> an unbuilt simulator
    cls: str = ""  # "module:Class" the factory must build
    render_options: dict = field(default_factory=dict)  # added to {"render": True}
    snapshot_is_free: bool = False  # taking a snapshot leaves the run as it would have been

    def rendering(self) -> Simulator:
        return self.make({"render": True, **self.render_options})

    def physics_only(self) -> Simulator:
        return self.make({"render": False})

    def simulator_class(self) -> type:
        module, name = (self.cls or "cab_core.contracts.simulator:Simulator").split(":")
        return getattr(importlib.import_module(module), name)


# what the project's backends are known to be; a backend installed from elsewhere gets the defaults
KNOWN = {
    # a snapshot is written back into the world it is taken from, so that run may differ from one
    # without it; replays are exact
    "sapien": dict(cls="cab_sim_sapien.simulator:SapienSimulator"),
    # TinyRenderer: it renders on any machine, so every check runs (snapshots as SAPIEN's)
    "pybullet": dict(cls="cab_sim_pybullet.simulator:PybulletSimulator", render_options={"renderer": "tiny"}),
    # taking the snapshot changes nothing: mj_getState reads the whole integration state
    "mujoco": dict(cls="cab_sim_mujoco.simulator:MujocoSimulator", snapshot_is_free=True),
}


def installed() -> list[str]:
    """The simulators the plugin registry serves."""
    return sorted(registry("simulators"))


@functools.cache
def backend(name: str) -> Backend:
    return Backend(name, registry("simulators")[name], **KNOWN.get(name, {}))


@functools.cache
def render_diagnosis(name: str) -> str | None:
    """None where backend ``name`` renders here, else why not (found out once a session)."""
    return sc.render_diagnosis(backend(name).rendering)


def require_renderer(name: str) -> None:
    """Skip the test, with the diagnosis, where backend ``name`` cannot render here."""
    why = render_diagnosis(name)
    if why is not None:
        pytest.skip(why)


def rendering_versions(name: str) -> dict:
    """``versions()`` of backend ``name`` rendering an empty scene (the test skipped where it cannot
    render here)."""
    require_renderer(name)
    sim = backend(name).rendering()
    sim.build(SceneSpec(), sc.make_embodiment())
    try:
        return sim.versions()
    finally:
        sim.close()


def registered_through_entry_point(b: Backend) -> None:
    """The plugin's entry point registers a factory under the backend's name that builds its class."""
    factory = registry("simulators", build_plugin_manager(autoload=True))[b.name]
    assert isinstance(factory({"render": False, "name": b.name}), b.simulator_class())


def bad_common_options_are_config_errors(b: Backend) -> None:
    """An unknown option, and a timestep that is not a positive number (a bool is not a duration),
    are refused when the simulator is made."""
    with pytest.raises(ConfigError, match="rendr"):
        b.make({"rendr": True})
    for bad in (-1, True):
        with pytest.raises(ConfigError, match="timestep must be a positive number"):
            b.make({"timestep": bad})


def timestep_option_overrides_the_scene(b: Backend) -> None:
    """The ``timestep`` option wins over the scene's and is reported in ``versions()``."""
    sim = b.make({"render": False, "timestep": 0.002})
    sim.build(sc.make_scene(), sc.make_embodiment())
    try:
        assert sim.timestep == 0.002
        assert sim.versions()["timestep"] == "0.002"
    finally:
        sim.close()


def physics_only_build_keeps_camera_geometry(b: Backend) -> None:
    """Without a renderer, camera names, sizes and poses still answer; pictures (and render samples)
    are refused."""
    sim = sc.build(b.physics_only)
    try:
        assert sorted(sim.camera_names()) == sorted([sc.HEAD_CAMERA, sc.WRIST_CAMERA])
        assert sim.camera_size(sc.WRIST_CAMERA) == (120, 160)
        assert sim.camera_pose(sc.WRIST_CAMERA).shape == (7,)
        with pytest.raises(RendererUnavailable, match="render: false"):
            sim.render(sc.HEAD_CAMERA)
        assert sim.render_sample() is None  # the episode then renders in the loop, and fails there
        assert sim.versions()["render"] == "off"
    finally:
        sim.close()


def snapshot_then_restore_replays_the_original_run(b: Backend) -> None:
    """Stronger than the suite: save, run, restore, run again == the run right after the save,
    bit for bit, in this instance and in a second build. Where the backend's ``snapshot_is_free``,
    also: a run in which the snapshot was taken == the same run without it."""
    physics_only = b.physics_only
    def run(sim):
        sc._motion_script(sim, 200, phase=60)
        return sc.world_state(sim)

    sim, other = sc.build(physics_only), sc.build(physics_only)
    plain = sc.build(physics_only) if b.snapshot_is_free else None
    try:
        sc._motion_script(sim, 60)
        snap = sim.save_state()
        original = run(sim)
        if plain is not None:
            sc._motion_script(plain, 60)
            sc._assert_bit_equal(original, run(plain), "a run without the snapshot")
        sim.restore_state(snap)
        sc._assert_bit_equal(original, run(sim), "replay in the same instance")
        other.restore_state(snap)
        sc._assert_bit_equal(original, run(other), "replay in another build")
        assert other.steps == sim.steps == 60 + 200
    finally:
        for s in (sim, other, plain):
            if s is not None:
                s.close()


def closed_simulator_refuses_calls(b: Backend) -> None:
    """After close(), commands raise SimulatorError."""
    sim = sc.build(b.physics_only)
    sim.close()
    with pytest.raises(SimulatorError):
        sim.step(1)
    with pytest.raises(SimulatorError):
        sim.get_qpos()


def contacts_survive_a_restore(b: Backend) -> None:
    """get_contacts() after a restore gives the snapshot's last-step contacts, not stale ones."""
    sim = sc.build(b.physics_only)
    try:
        sim.step(100)
        snap = sim.save_state()
        before = sim.get_contacts()
        sim.set_object_pose("cube", (0.1, 0.0, 1.2, 1, 0, 0, 0))
        sim.step(5)  # the cube is in the air now
        assert not any("cube" in (c.a, c.b) for c in sim.get_contacts())
        sim.restore_state(snap)
        assert sim.get_contacts() == before
    finally:
        sim.close()


def physics_only_steps_like_a_rendering_build(b: Backend) -> None:
    """Visual shapes, cameras and taking a picture do not touch the physics: both builds step
    bit-identically (skipped where the backend cannot render here)."""
    require_renderer(b.name)
    on, off = sc.build(b.rendering), sc.build(b.physics_only)
    try:
        sc._motion_script(on, 200)
        on.render(sc.HEAD_CAMERA)
        sc._motion_script(off, 200)
        sc._assert_bit_equal(sc.world_state(on), sc.world_state(off), "render on vs off")
    finally:
        on.close()
        off.close()


# every check above, in the order tests/test_sim_backends.py runs them on each backend
CHECKS = (registered_through_entry_point, bad_common_options_are_config_errors, timestep_option_overrides_the_scene,
          physics_only_build_keeps_camera_geometry, snapshot_then_restore_replays_the_original_run,
          closed_simulator_refuses_calls, contacts_survive_a_restore, physics_only_steps_like_a_rendering_build)
