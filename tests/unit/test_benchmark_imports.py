"""Every name a benchmark imports from the package exists, including imports made inside functions: a renamed or
removed name must fail here, not halfway through a long benchmark run (`benchmarks.reduced --stress` once did)."""
import ast
import importlib
import importlib.util
from pathlib import Path

import pytest

BENCHMARKS = sorted((Path(__file__).resolve().parents[2] / "benchmarks").glob("*.py"))


def imported_names(path: Path) -> list[tuple[str, str]]:
    """(module, name) of every `from railswitch... import name` anywhere in the file."""
    tree = ast.parse(path.read_text())
    return [(node.module, alias.name) for node in ast.walk(tree)
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("railswitch")
            for alias in node.names]


@pytest.mark.parametrize("path", BENCHMARKS, ids=lambda p: p.stem)
def test_benchmark_imports_resolve(path):
    for module, name in imported_names(path):
        target = importlib.import_module(module)
        assert hasattr(target, name) or importlib.util.find_spec(f"{module}.{name}") is not None, \
            f"{path.name}: {module} has no {name}"


def test_the_papers_estimator_takes_every_argument_the_diagnosis_passes_its_fits():
    """benchmarks.paper_de overrides ThrowEstimator.fit: a keyword the diagnosis adds to its fits must reach the
    override too (`beaten` once failed benchmarks.diagnosis only at its last part, the paper's estimator)."""
    import inspect

    from benchmarks.paper_de import PaperEstimator
    from railswitch.models.diagnosis.estimation import ThrowEstimator

    ours = inspect.signature(ThrowEstimator.fit).parameters
    theirs = inspect.signature(PaperEstimator.fit).parameters
    assert list(theirs) == list(ours)


def test_a_switch_s_outcome_names_its_faults_as_a_diagnosis_does():
    """benchmarks.diagnosis judges the paper's estimator and ours by the Outcome of a SwitchDiagnoser, as the others
    judge a Diagnosis, with named() (its absence once stopped benchmarks.diagnosis at its last part)."""
    from railswitch.models.diagnosis.switch_diagnoser import Outcome

    assert Outcome("left_bolt", None, None, None, faults=("left_bolt", "missing_bearing")).named() == \
        "left_bolt+missing_bearing"
    assert Outcome("nominal", None, None, None).named() == "nominal"
    assert Outcome("unknown", "cut short", None, None).named() == "unknown"
