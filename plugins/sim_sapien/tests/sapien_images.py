"""Renders every camera of a task's initial scene on SAPIEN in a fresh process (the BRDF table and
the Vulkan device are per process): ``python sapien_images.py '<options json>' out.npz task...``.
Writes the images and what the simulator recorded about its BRDF table. The option ``env_faces``
(six image files) lights the scene with an environment map as well, the light that the BRDF table
weighs (cab's scenes have none: their specular image-based light is zero whatever the table)."""
from __future__ import annotations

import json
import sys

import numpy as np

from cab_core.plugins import all_tasks, create


def main() -> None:
    options, out, tasks = json.loads(sys.argv[1]), sys.argv[2], sys.argv[3:]
    faces = options.pop("env_faces", None)
    images, sources = {}, []
    emb = create("embodiments", "aloha_agilex", {})
    for name in tasks:
        task = all_tasks()[name]
        inst = task.build(task.info.seed, emb)
        sim = create("simulators", "sapien", {"name": "sapien", **options})
        try:
            sim.build(inst.scene, emb)
            if faces:
                import sapien

                sim._scene.set_environment_map(sapien.render.RenderCubemap(*faces))
            for cam in ("head_camera", "left_camera", "right_camera"):
                images[f"{name}/{cam}"] = sim.render(cam)
            sources.append(sim.versions()["brdf_lut"])
        finally:
            sim.close()
    np.savez(out, sources=np.array(sources), **images)


if __name__ == "__main__":
    main()
