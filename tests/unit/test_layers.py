"""The rooms keep their layers (docs/architecture.md): the import-linter contracts in pyproject.toml hold."""
from pathlib import Path

from importlinter.cli import lint_imports

PYPROJECT = Path(__file__).resolve().parents[2] / "pyproject.toml"


def test_the_import_contracts_of_pyproject_hold():
    assert lint_imports(config_filename=str(PYPROJECT), no_cache=True) == 0  # its report names each broken import
