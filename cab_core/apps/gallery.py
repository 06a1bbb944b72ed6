"""``cab-gallery``: the head-camera image of every task's initial scene (catalog seed), with a
Markdown page that shows the suite at a glance."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def render_all(out: Path, tasks: list[str] | None = None, sim_name: str | None = None) -> list[tuple[str, str]]:
    """``sim_name`` and the robot: the default configuration's (cab_core.config.default_selection)."""
    import numpy as np
    from PIL import Image

    from cab_core.config import default_selection
    from cab_core.plugins import all_tasks, create

    installed = all_tasks()
    names = tasks or list(installed)
    d = default_selection(("sim", "embodiment"))
    sim_name = sim_name or d["sim"]
    emb = create("embodiments", d["embodiment"], {})
    out.mkdir(parents=True, exist_ok=True)
    done = []
    for name in names:
        task = installed[name]
        inst = task.build(task.info.seed, emb)
        sim = create("simulators", sim_name, {"name": sim_name})
        try:
            sim.build(inst.scene, emb)
            sim.step(task.settle_steps())
            img = sim.render("head_camera")
        finally:
            sim.close()
        Image.fromarray(np.asarray(img)).save(out / f"{name}.png", optimize=True)
        done.append((name, task.info.instruction))
        print(f"  {name}", file=sys.stderr, flush=True)
    return done


def write_page(out: Path, items: list[tuple[str, str]]) -> None:
    lines = ["# The task gallery", "",
             "The head-camera view (640x480) of every task's initial scene at its catalog seed, as the agent "
             "first sees it. Regenerate with `cab-gallery --out docs/gallery`.", ""]
    for name, instruction in items:
        lines += [f"## {name}", "", f"> {instruction}", "", f"![{name}]({name}.png)", ""]
    (out / "README.md").write_text("\n".join(lines))


def main() -> None:
    ap = argparse.ArgumentParser(prog="cab-gallery", description=__doc__)
    ap.add_argument("--out", default="outputs/gallery", help="folder for the PNGs and README.md")
    ap.add_argument("--tasks", default=None, help="comma-separated task names (default: all installed)")
    a = ap.parse_args()
    out = Path(a.out)
    items = render_all(out, a.tasks.split(",") if a.tasks else None)
    write_page(out, items)
    print(f"wrote {len(items)} images and README.md to {out}")
