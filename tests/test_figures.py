"""The report's figures (matplotlib, cab_core/analysis/figures.py) on the shared sweep: the files
beside report.md (PDF, SVG, PNG of each), the inline SVG of report.html (one mark per bar, segment,
line or point, each titled), reproducible bytes, and matplotlib imported only when a report is drawn."""
import json
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
from PIL import Image

from cab_core.analysis import figures as fg
from cab_core.analysis import report as rep
from cab_core.analysis.failure import LABELS, STAGES
from cab_core.analysis.measures import CLAIMS
from cab_core.apps.report_cli import main as report_main

NS = "{http://www.w3.org/2000/svg}"
NAMES = ["success", "outcomes", "claims", "coverage", "coverage_curve", "success_wall"]  # no cost in these records


@pytest.fixture(scope="module")
def built(sweep, tmp_path_factory):
    out = tmp_path_factory.mktemp("figures")
    return rep.write(sweep, out, views=False), out


def marks(svg: ET.Element, prefix: str) -> dict[str, str]:
    """id -> title of each marked group whose id starts with ``prefix``."""
    return {g.get("id"): g.find(f"{NS}title").text for g in svg.iter(f"{NS}g") if g.get("id", "").startswith(prefix)}


def inline(out) -> dict[str, ET.Element]:
    page = (out / "report.html").read_text()
    svgs = [ET.fromstring(s) for s in re.findall(r"<svg.*?</svg>", page, re.S)]
    return {s.get("data-figure"): s for s in svgs}


@pytest.mark.sim
def test_files_beside_the_report(built):
    r, out = built
    assert all(c["cost_total"] is None for c in r["configs"])  # scripted agents: no usage, no cost figure
    for name in NAMES:
        fig = out / "figures" / name
        pdf = fig.with_suffix(".pdf").read_bytes()
        assert pdf.startswith(b"%PDF-") and pdf.rstrip().endswith(b"%%EOF")
        with Image.open(fig.with_suffix(".png")) as im:
            im.load()
            assert im.format == "PNG" and im.size[0] == round(fg.WIDTH * fg.PNG_DPI) and im.size[1] > 200
        svg = ET.fromstring(fig.with_suffix(".svg").read_bytes())
        assert svg.tag == f"{NS}svg" and svg.find(f"{NS}title").text
    assert sorted(p.name for p in (out / "figures").iterdir()) == sorted(f"{n}.{x}" for n in NAMES for x in fg.FORMATS)
    md = (out / "report.md").read_text()
    for name in NAMES:  # listed in report.md: the SVG shown, each format linked
        assert f"(figures/{name}.svg)" in md and f"[PDF](figures/{name}.pdf)" in md and f"[PNG](figures/{name}.png)" in md


@pytest.mark.sim
def test_inline_figures_show_every_mark(built):
    r, out = built
    figs = inline(out)
    assert list(figs) == NAMES  # in page order
    page = (out / "report.html").read_text()
    ids = re.findall(r'\bid="([^"]+)"', page)
    assert len(ids) == len(set(ids))  # several inline SVGs on one page: no id twice
    cs = r["configs"]
    n = len(cs)
    # success: one bar per configuration, its title the rate and the Wilson interval
    assert list(marks(figs["success"], "success-bar-").values()) == [
        f"{c['config']}: {rep.pct(c['success_rate'])} (interval {rep.pct(c['wilson95'][0])}–{rep.pct(c['wilson95'][1])})"
        for c in cs]
    # outcomes: a segment per non-zero count (successes, then each failure stage)
    want = [f"{c['config']}, {part}: {v}" for c in cs
            for part, v in zip(["Success"] + [LABELS[s] for s in STAGES],
                               [c["successes"]] + [c["failure_stages"].get(s, 0) for s in STAGES]) if v]
    assert list(marks(figs["outcomes"], "outcomes-seg-").values()) == want
    assert sum(int(t.rsplit(": ", 1)[1]) for t in want) == r["attempts"]
    want = [f"{c['config']}, {k}: {c['claims'][k]}" for c in cs for k in CLAIMS if c["claims"][k]]
    assert list(marks(figs["claims"], "claims-seg-").values()) == want
    assert len(marks(figs["coverage"], "coverage-bar-")) == 2 * n  # subgoal and spatial per configuration
    assert len(marks(figs["coverage_curve"], "coverage_curve-line-")) == n
    points = marks(figs["success_wall"], "success_wall-point-")
    assert len(points) == n and all(c["config"] in t for c, t in zip(cs, points.values()))
    for svg in figs.values():  # a point is one marker, a bar one path
        for g in svg.iter(f"{NS}g"):
            if re.search(r"-(point|bar|seg)-", g.get("id", "")):
                assert len(g.findall(f"{NS}path") + g.findall(f".//{NS}use")) == 1


@pytest.mark.sim
def test_the_same_report_is_the_same_bytes(built, sweep, tmp_path):
    _, out = built
    rep.write(sweep, tmp_path, views=False)
    for p in sorted((out / "figures").iterdir()) + [out / "report.html", out / "report.md"]:
        assert (tmp_path / p.relative_to(out)).read_bytes() == p.read_bytes(), p.name


def test_inline_svg_is_embeddable_and_reproducible():
    def draw():
        return fg.stacked("t", "A <title> & more", [("a", [1, 0, 2]), ("b", [0, 3, 0])], ["x", "y", "z"])

    one, two = fg.inline_svg(draw()), fg.inline_svg(draw())
    assert one == two and one.startswith("<svg ") and "<?xml" not in one and "<metadata" not in one
    svg = ET.fromstring(one)
    assert svg.get("aria-label") == "A <title> & more" and svg.find(f"{NS}title").text == "A <title> & more"
    assert all(i.startswith("t-") for i in re.findall(r'\bid="([^"]+)"', one))
    refs = re.findall(r'(?:href="#|url\(#)([^")]+)', one)
    assert refs and set(refs) <= set(re.findall(r'\bid="([^"]+)"', one))  # every reference resolves
    assert list(marks(svg, "t-seg-").values()) == ["a, x: 1", "a, z: 2", "b, y: 3"]


def test_matplotlib_is_imported_only_to_draw():
    code = ("import sys, cab_core.apps.cli, cab_core.analysis.report, cab_core.analysis.viewer; "
            "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib')))")
    out = subprocess.run([sys.executable, "-c", "import json; " + code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []


@pytest.mark.sim
def test_no_figure_files(built, sweep, tmp_path, capsys):
    report_main([str(sweep), "--out", str(tmp_path), "--no-views", "--no-figure-files"])
    assert not (tmp_path / "figures").exists() and "## Figures" not in (tmp_path / "report.md").read_text()
    assert list(inline(tmp_path)) == NAMES  # the page shows them all the same
    assert "figures/" not in capsys.readouterr().err
    assert (tmp_path / "report.html").read_bytes() == (built[1] / "report.html").read_bytes()  # one layout either way
