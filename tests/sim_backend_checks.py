"""Checks the simulator backend tests (tests/test_sim_<backend>.py) share, beyond the conformance
suite of :mod:`cab_core.testing.sim_conformance` (which ``pytest --cab-conformance`` runs on every
installed backend, with and without a renderer): plugin registration, options, the physics-only
mode and the snapshot, contact and shutdown guarantees every backend gives.

Each check takes the backend's simulator factories (``rendering``: a simulator that renders,
``physics_only``: one built with ``render: false``), so a test module states only what is its own.
"""
from __future__ import annotations

from typing import Callable

import pytest

from cab_core.errors import RendererUnavailable, SimulatorError
from cab_core.contracts.simulator import Simulator
from cab_core.testing import sim_conformance as sc

SimFactory = Callable[[], Simulator]


render_diagnosis = sc.render_diagnosis  # None where the backend renders here, else why not


def registered_through_entry_point(backend: str, cls: type) -> None:
    """The plugin's entry point registers a factory under ``backend`` that builds ``cls``."""
    from cab_core.plugins import build_plugin_manager, registry

    factory = registry("simulators", build_plugin_manager(autoload=True))[backend]
    assert isinstance(factory({"render": False, "name": backend}), cls)


def timestep_option_overrides_the_scene(cls: type) -> None:
    """The ``timestep`` option wins over the scene's and is reported in ``versions()``."""
    sim = cls({"render": False, "timestep": 0.002})
    sim.build(sc.make_scene(), sc.make_embodiment())
    try:
        assert sim.timestep == 0.002
        assert sim.versions()["timestep"] == "0.002"
    finally:
        sim.close()


def physics_only_build_keeps_camera_geometry(physics_only: SimFactory) -> None:
    """Without a renderer, camera names, sizes and poses still answer; pictures (and render samples)
    are refused."""
    sim = sc.build(physics_only)
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


def snapshot_then_restore_replays_the_original_run(physics_only: SimFactory, snapshot_is_free: bool) -> None:
    """Stronger than the suite: save, run, restore, run again == the run right after the save,
    bit for bit, in this instance and in a second build. With ``snapshot_is_free``, also: a run
    in which the snapshot was taken == the same run without it."""
    def run(sim):
        sc._motion_script(sim, 200, phase=60)
        return sc.world_state(sim)

    sim, other = sc.build(physics_only), sc.build(physics_only)
    plain = sc.build(physics_only) if snapshot_is_free else None
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


def closed_simulator_refuses_calls(physics_only: SimFactory) -> None:
    """After close(), commands raise SimulatorError."""
    sim = sc.build(physics_only)
    sim.close()
    with pytest.raises(SimulatorError):
        sim.step(1)
    with pytest.raises(SimulatorError):
        sim.get_qpos()


def contacts_survive_a_restore(physics_only: SimFactory) -> None:
    """get_contacts() after a restore gives the snapshot's last-step contacts, not stale ones."""
    sim = sc.build(physics_only)
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


def physics_only_steps_like_a_rendering_build(rendering: SimFactory, physics_only: SimFactory) -> None:
    """Visual shapes, cameras and taking a picture do not touch the physics: both builds step
    bit-identically."""
    a, b = sc.build(rendering), sc.build(physics_only)
    try:
        sc._motion_script(a, 200)
        a.render(sc.HEAD_CAMERA)
        sc._motion_script(b, 200)
        sc._assert_bit_equal(sc.world_state(a), sc.world_state(b), "render on vs off")
    finally:
        a.close()
        b.close()
