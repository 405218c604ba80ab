"""The manual a newcomer reads: a short README whose links resolve, a user guide that has every command, and a
results file that only benchmarks.report writes."""
import json
import re
from pathlib import Path

from benchmarks.report import RUNS, columns, kept_runs, render
from railswitch.services.commands.cli import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
README_LINES = 150  # a first screen or two: the commands, the picture, the three ways in, links


def test_the_readme_is_short_and_starts_with_the_demo_and_the_test_command():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_LINES, f"README.md has {len(lines)} lines"
    commands = lines[lines.index("```bash") + 1:lines.index("```bash") + 3]
    assert commands == ["pip install -e . && railswitch demo", 'pip install -e ".[test]" && python -m pytest -q']


def test_every_relative_link_and_picture_of_the_readme_and_the_docs_exists():
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if "://" not in target:
                assert (page.parent / target).exists(), f"{page.name} links {target}, which does not exist"


def test_the_user_guide_has_a_section_for_every_command():
    guide = (ROOT / "docs" / "user-guide.md").read_text()
    headings = [line for line in guide.splitlines() if line.startswith("#")]
    missing = [name for name in COMMANDS if not any(f"`railswitch {name}" in line for line in headings)]
    assert missing == []


def test_the_results_file_tabulates_each_representation_of_a_kept_run_and_says_which_were_not_run():
    per_model = next(run for run in RUNS if run.per_model)
    results = {f"{per_model.benchmark}-poly": {"latency_ms": {"p50": 32.5}, "cases": [1, 2], "isolation": 1.0},
               f"{per_model.benchmark}-nn": {"latency_ms": {"p50": 30.25}, "isolation": 0.98}}
    cols = columns(per_model, results)
    assert cols == {"poly": {"latency_ms.p50": 32.5, "isolation": 1.0},
                    "nn": {"latency_ms.p50": 30.25, "isolation": 0.98}}  # lists stay in the kept JSON
    text = render(results, {name: f"python -m benchmarks.{per_model.benchmark}" for name in results})
    assert "| `latency_ms.p50` | 32.5 | 30.25 |" in text
    assert text.count("Not run for this file.") == len(RUNS) - 1


def test_a_benchmark_run_twice_keeps_a_table_each_and_only_database_runs_take_the_database():
    runs = [run for run in RUNS if run.benchmark == "bus"]
    assert len({run.key for run in runs}) == len(runs) > 1  # each its own kept JSON and --only name
    results = {run.key: {"figure": k} for k, run in enumerate(runs)}
    assert [columns(run, results) for run in runs] == [{"value": {"figure": k}} for k in range(len(runs))]
    url = "postgresql://u@127.0.0.1:5/db"
    takes = {run.key: run.command(run.names()[0], url)[-2:] == ["--db", url] for run in RUNS}
    assert {key for key, took in takes.items() if took} == {"historian", "soak"}
    assert all("--db" not in run.command(run.names()[0]) for run in RUNS)  # without a URL, none


def test_the_results_file_is_what_its_kept_runs_render():
    """docs/results.md is rewritten from docs/results/*.json, never edited: rendered again from them, it is the same
    but for when and at which commit it was written; each kept run names the commit it ran at."""
    kept = ROOT / "docs" / "results"
    results, sources, ran = kept_runs(kept)
    assert results, "no kept runs in docs/results"
    assert all(json.loads(path.read_text()).get("commit") for path in kept.glob("*.json"))

    def body(text: str) -> list[str]:
        return [line for line in text.splitlines() if not line.startswith(("- written", "- machine"))]
    assert body(render(results, sources, ran)) == body((ROOT / "docs" / "results.md").read_text())
