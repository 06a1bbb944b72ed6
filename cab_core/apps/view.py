"""``cab-view <dir>``: write the page of one attempt (:func:`cab_core.analysis.viewer.write_view`)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cab_core.analysis.viewer import write_view
from cab_core.errors import CabError


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="cab-view", description="Write view.html for one attempt directory.")
    ap.add_argument("dir", help="an attempt directory (finished, running or interrupted)")
    a = ap.parse_args(argv)
    try:
        page = write_view(Path(a.dir))
    except CabError as e:
        print(f"cab-view: {e}", file=sys.stderr)
        sys.exit(2)
    print(page)
