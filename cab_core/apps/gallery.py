"""``cab-gallery``: the head-camera image of every task's initial scene (catalog seed), with a
Markdown page that shows the suite at a glance. ``--randomize OPTION`` (``cab_core.attempt.variation.randomize``)
adds, beside each plain image, the same scene under that appearance randomisation, drawn from
``--seed`` as an attempt at that seed draws it."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cab_core.attempt.variation.randomize import Randomization, randomize_instance
from cab_core.config import composed, default_selection
from cab_core.plugins import all_tasks, create


def _randomization(option: str | None):
    if option is None:
        return None
    return Randomization.from_cfg(composed([f"randomize={option}"]).get("randomize"))


def render_all(out: Path, tasks: list[str] | None = None, sim_name: str | None = None,
               randomize: str | None = None, seed: int | None = None) -> list[tuple[str, str]]:
    """``sim_name`` and the robot: the default configuration's (cab_core.config.default_selection).
    ``randomize``: also each scene under that randomisation option (``<task>-<option>.png``)."""
    import numpy as np
    from PIL import Image

    installed = all_tasks()
    names = tasks or list(installed)
    d = default_selection(("sim", "embodiment"))
    sim_name = sim_name or d["sim"]
    emb = create("embodiments", d["embodiment"], {})
    out.mkdir(parents=True, exist_ok=True)
    done = []
    rnd = _randomization(randomize)
    for name in names:
        task = installed[name]
        s = task.info.seed if seed is None else seed
        looks = [("", None)] + ([(f"-{randomize}", rnd)] if rnd is not None else [])
        for suffix, r in looks:
            inst = task.build(s, emb)
            built = emb
            if r is not None:
                built, _ = randomize_instance(inst.scene, emb, r, s, name, task.info.instruction,
                                              task.distractor_slots(inst) if "distractors" in r.parts else [])
            sim = create("simulators", sim_name, {"name": sim_name})
            try:
                sim.build(inst.scene, built)
                sim.step(task.settle_steps())
                img = sim.render("head_camera")
            finally:
                sim.close()
            Image.fromarray(np.asarray(img)).save(out / f"{name}{suffix}.png", optimize=True)
        done.append((name, task.info.instruction))
        print(f"  {name}", file=sys.stderr, flush=True)
    return done


def write_page(out: Path, items: list[tuple[str, str]], randomize: str | None = None, seed: int | None = None,
               sim: str | None = None) -> None:
    """The page; its command to regenerate names ``out`` as given when relative (a page under docs/
    never names a machine path), by its folder name otherwise."""
    at = "its catalog seed" if seed is None else f"seed {seed}"
    shown = out.as_posix() if not out.is_absolute() else out.name
    lines = ["# The task gallery", "",
             f"The head-camera view (640x480) of every task's initial scene at {at}, as the agent "
             "first sees it" + (f", and beside it the same scene under `randomize={randomize}` (appearance "
                                "randomisation drawn from the seed)" if randomize else "")
             + f". Regenerate with `cab-gallery --out {shown}" + (f" --sim {sim}" if sim else "")
             + (f" --randomize {randomize}" if randomize else "") + (f" --seed {seed}" if seed is not None else "") + "`.",
             ""]
    for name, instruction in items:
        pics = f"![{name}]({name}.png)" + (f" ![{name}, randomize={randomize}]({name}-{randomize}.png)" if randomize else "")
        lines += [f"## {name}", "", f"> {instruction}", "", pics, ""]
    (out / "README.md").write_text("\n".join(lines))


def main() -> None:
    ap = argparse.ArgumentParser(prog="cab-gallery", description=__doc__)
    ap.add_argument("--out", default="outputs/gallery", help="folder for the PNGs and README.md")
    ap.add_argument("--tasks", default=None, help="comma-separated task names (default: all installed)")
    ap.add_argument("--randomize", default=None, metavar="OPTION",
                    help="also each scene under this appearance randomisation (lighting, textures, camera, distractors, all)")
    ap.add_argument("--seed", type=int, default=None, help="the scene seed (default: each task's catalog seed)")
    ap.add_argument("--sim", default=None, help="the simulator (default: the default configuration's)")
    a = ap.parse_args()
    out = Path(a.out)
    try:
        _randomization(a.randomize)
    except Exception:
        ap.error(f"unknown --randomize option {a.randomize!r}")
    items = render_all(out, a.tasks.split(",") if a.tasks else None, a.sim, a.randomize, a.seed)
    write_page(out, items, a.randomize, a.seed, a.sim)
    print(f"wrote {len(items)} images and README.md to {out}")
