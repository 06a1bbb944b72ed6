"""Kits for the people who extend cab: what a task suite (``cab_core.kits.task``, its oracle helpers)
and a model harness (``cab_core.kits.harness``) import, apart from the engine's internals and from
any one suite. With ``cab_core.contracts``, ``cab_core.errors`` and ``cab_core.geometry`` they are
the public surface a plugin builds on (docs/plugins.md).

The task kit:

* :mod:`~cab_core.kits.scene`: the world's constants, colours and materials, the base scene (table,
  wall, lighting), the seeded pose sampler (``rand_pose``, ``sample_until``), pose helpers;
* :mod:`~cab_core.kits.assets`: generated meshes and URDFs in cab's cache;
* :mod:`~cab_core.kits.task`: ``SceneTask`` (a task on the base scene that declares its own
  metadata), the grippers-open and latched verifier bases;
* :mod:`~cab_core.kits.margins`: the margin constructors and ``grippers_open``;
* :mod:`~cab_core.kits.oracle`: ``Hands``, ``BothHands``, grasp orientations, ``resume`` (a
  reference solution run from any state a fork starts from);
* :mod:`~cab_core.kits.stages`: which step of a reference solution the state shows done.

Units: metres, radians, kilograms, seconds; poses [x, y, z, qw, qx, qy, qz] (quaternions w first,
as in :mod:`cab_core.geometry`). The kits import only the contracts, ``errors``, ``geometry``,
``numerics`` and one another."""
