"""The paper's published figures (cab_suite_codeaction/data/paper_figures.yaml): every transcribed
number equals the paper's, read again here from the seed's LaTeX rows (where ``../shared/seed`` is
present), the mapping to cab's model configurations names configurations that exist, and the figures
reach the core through the hook ``cab_published_figures`` only."""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from cab_core.errors import ConfigError
from cab_core.plugins import build_plugin_manager, registry
from cab_suite_codeaction import paper_figures

SEEDS = sorted((Path(__file__).resolve().parents[1].parent / "shared" / "seed").glob("000_*.txt"))
FIGURES = paper_figures.published_figures()
CONFIGS = FIGURES["configurations"]
NAMES = [c["name"] for c in CONFIGS]
TOOLS = ("plane_intersect", "triangulate_correspondence", "scale_from_gripper", "scale_from_object_size",
         "probe_contact_along")  # the paper's column order (ray-plane, triangulation, gripper, size prior, probe)


@pytest.fixture(scope="module")
def seed() -> str:
    if not SEEDS:
        pytest.skip("the seed paper (../shared/seed/000_*.txt beside the checkout) is not present")
    return SEEDS[0].read_text(encoding="utf-8")


def table(text: str, label: str) -> str:
    """The LaTeX of the table labelled ``label``, from its label to its ``\\bottomrule``."""
    start = text.index("\\label{" + label + "}")
    return text[start:text.index(r"\bottomrule", start)]


def row_numbers(text: str, label: str, name: str) -> list[str]:
    """The numbers of the row of configuration ``name`` in table ``label``, in reading order, as printed
    (bold, thousands separators and percent signs removed; '--' kept as a cell of its own)."""
    rows = [line for line in table(text, label).splitlines() if line.strip().startswith(name + " &")]
    assert len(rows) == 1, f"{label}: {len(rows)} rows for {name!r}"
    cells = rows[0].strip().removesuffix("\\\\").split("&")[1:]
    out: list[str] = []
    for cell in cells:
        cell = re.sub(r"\\textbf\{([^}]*)\}", r"\1", cell).replace(",", "").strip()
        out += ["--"] if cell == "--" else re.findall(r"\d+(?:\.\d+)?", cell)
    return out


def printed(v) -> str:
    """A transcribed value as the paper prints it (the YAML keeps 52.00 as 52.0: compare as numbers)."""
    return "--" if v is None else str(v)


def same(found: list[str], expected: list) -> None:
    assert len(found) == len(expected), (found, expected)
    for f, e in zip(found, expected):
        if e is None or f == "--":
            assert printed(e) == f, (found, expected)
        else:
            assert float(f) == pytest.approx(float(e), abs=0), (found, expected)


def test_every_configuration_of_the_paper_is_transcribed_once(seed):
    names = [line.split("&")[0].strip() for line in table(seed, "tab:consistency").splitlines()
             if "&" in line and "(" in line.split("&")[0]]
    assert names == NAMES
    for block in paper_figures.BLOCKS:
        label = FIGURES["tables"][block]["label"]
        assert FIGURES["tables"][block]["caption"] in seed[:seed.index("\\label{" + label + "}") + 1][-3000:], block


@pytest.mark.parametrize("name", NAMES)
def test_every_number_of_the_row_equals_the_paper(seed, name):
    c = next(x for x in CONFIGS if x["name"] == name)
    k = c["consistency"]
    same(row_numbers(seed, "tab:consistency", name),
         [k["success"], k["coverage"], *(k["tasks_by_successes"][f"{i}/3"] for i in range(4))])
    u = c["resource_use"]
    same(row_numbers(seed, "tab:main", name),
         [u["calls_mean"], u["sim_seconds_median"], u["wall_seconds_median"], u["wait_seconds_median"],
          u["cost_total_usd"], u["cost_median_usd"], *u["cost_iqr_usd"]])
    t = c["termination"]
    same(row_numbers(seed, "tab:termination", name),
         [*(t["stopping"][s] for s in ("done", "tool", "phys", "other")),
          *(t["claims"][s] for s in ("correct", "over", "under", "absent"))])
    p = c["programs"]
    same(row_numbers(seed, "tab:policy-programs", name),
         [p["program_share_pct"], p["program_errors"], p["programs_returned"], p["program_error_rate_pct"]])
    a = c["actions"]
    same(row_numbers(seed, "tab:motion-failures", name),
         [a["not_completed"], a["actions"], a["not_completed_rate_pct"],
          *(a["by_cause"][s] for s in ("planner", "stall", "deviation", "allowance"))])
    assert list(c["tool_use"]) == list(TOOLS)
    same(row_numbers(seed, "tab:estimation-outcomes", name),
         [x for tool in TOOLS for x in (c["tool_use"][tool]["rate_pct"], c["tool_use"][tool]["successes"],
                                        c["tool_use"][tool]["attempts"])])
    ids = [line for line in table(seed, "tab:agent-settings").splitlines() if line.startswith(name + " &")]
    assert re.search(r"\\texttt\{([^}]*)\}", ids[0]).group(1) == c["model_id"]


def test_the_completion_judgment_table_column_by_column(seed):
    text = table(seed, "tab:completion-judgment")
    rows = re.findall(r"&\s*(\d+)/(\d+) \(([\d.]+)\\%\)\s*&\s*(\d+)/(\d+) \(([\d.]+)\\%\)\s*&\s*(\d+)/(\d+) \(([\d.]+)\\%\)",
                      text)
    keys = ["done", "correct_claim", "success_correct", "success_under", "success_absent", "failure_correct",
            "failure_over", "failure_absent"]
    assert len(rows) == len(keys)
    columns = ["GPT-6 Astra (Codex CLI)", "Claude Opus 5 (Reference)", "Claude Opus 5 (Claude Code)"]
    assert [c["name"] for c in CONFIGS if "completion_judgment" in c] == columns
    for j, name in enumerate(columns):
        got = next(c for c in CONFIGS if c["name"] == name)["completion_judgment"]
        assert list(got) == keys
        for key, row in zip(keys, rows):
            same(list(row[3 * j:3 * j + 3]), got[key])


def test_the_blocks_agree_with_each_other():
    """Counts the paper prints twice agree (a typo in one transcription would break one of them)."""
    for c in CONFIGS:
        k, t, j = c["consistency"], c["termination"], c.get("completion_judgment")
        assert sum(k["tasks_by_successes"].values()) == FIGURES["source"]["tasks"]
        assert sum(n * i for i, n in enumerate(k["tasks_by_successes"].values())) == k["success"]
        assert 25 - k["tasks_by_successes"]["0/3"] == k["coverage"]
        assert sum(t["stopping"].values()) == sum(t["claims"].values()) == FIGURES["source"]["attempts_per_configuration"]
        assert sum(c["actions"]["by_cause"].values()) == c["actions"]["not_completed"]
        if j:
            assert j["done"][0] == t["stopping"]["done"] and j["correct_claim"][0] == t["claims"]["correct"]
            assert j["success_correct"][1] == k["success"] and j["failure_over"][0] == t["claims"]["over"]


def test_the_mapping_names_cab_model_configurations():
    """Each paper configuration maps to a model configuration a harness plugin ships, with its
    harness and model id."""
    roots = {"reference": "harness_reference/cab_harness_reference", "codex": "harness_mcp/cab_harness_mcp",
             "claude_code": "harness_mcp/cab_harness_mcp"}
    plugins = Path(__file__).resolve().parents[1] / "plugins"
    for c in CONFIGS:
        conf = plugins / roots[c["cab"]["harness"]] / "conf" / "model" / f"{c['cab']['model']}.yaml"
        data = yaml.safe_load(conf.read_text())
        assert (data["name"], data["harness"], data["model_id"]) == (c["cab"]["model"], c["cab"]["harness"],
                                                                    c["model_id"]), conf.name


def test_the_core_reads_the_figures_through_the_hook_alone():
    assert registry("published_figures")["paper"]() == FIGURES
    assert registry("published_figures", build_plugin_manager(autoload=False)) == {}


def test_a_malformed_file_is_one_config_error(monkeypatch):
    bad = {"tables": {}, "configurations": [{"name": "X (Reference)", "cab": {"model": "x", "harness": "reference"},
                                              "consistency": {"success": 1}}]}
    paper_figures._load.cache_clear()
    monkeypatch.setattr(yaml, "safe_load", lambda text: bad)
    try:
        with pytest.raises(ConfigError, match="block\\(s\\) consistency name no table"):
            paper_figures.published_figures()
        bad["configurations"][0]["cab"] = {"model": "x"}
        paper_figures._load.cache_clear()
        with pytest.raises(ConfigError, match="lacks cab: \\{model, harness\\}"):
            paper_figures.published_figures()
    finally:
        paper_figures._load.cache_clear()
