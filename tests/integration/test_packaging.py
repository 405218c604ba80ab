"""The installed package: one `railswitch` namespace, shipped weights inside it, user models beside it."""
import hashlib
import json
import os
import shutil
import subprocess
import sys

from tests.live import ROOT


def test_a_non_editable_install_imports_as_railswitch_only(tmp_path):
    source, target = tmp_path / "source", tmp_path / "site"  # a copy: building writes build/ beside the sources
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".git", "*venv*", "build", "*.egg-info", "out",
                                                                  "__pycache__", ".pytest_cache"))
    build = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--quiet",
                            "--target", str(target), str(source)], capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stderr
    probe = ("import importlib.util, railswitch.models.plant.high_fidelity as plant, railswitch.services.commands.cli;"
             "print(plant.__file__);"
             "print([name for name in ('models', 'schemas', 'services') if importlib.util.find_spec(name)])")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = subprocess.run([sys.executable, "-c", probe], cwd=elsewhere, capture_output=True, text=True, timeout=120,
                            env={**os.environ, "PYTHONPATH": str(target)})
    assert result.returncode == 0, result.stderr
    where, stray = result.stdout.splitlines()
    assert where.startswith(str(target / "railswitch" / "models"))
    assert stray == "[]"  # no generic top-level models, schemas or services packages
    assert sorted(p.name for p in (target / "railswitch" / "models" / "params").glob("*.json")) == [
        "causal.json", "nn.json", "poly.json"]


def test_train_writes_to_the_user_directory_which_then_takes_precedence_over_the_shipped_weights(tmp_path):
    shipped = ROOT / "models" / "params" / "poly.json"
    before = hashlib.sha256(shipped.read_bytes()).hexdigest()
    env = {**os.environ, "RAILSWITCH_MODELS": str(tmp_path)}
    trained = subprocess.run([sys.executable, "-m", "railswitch", "train", "--model", "poly", "--iterations", "2"],
                             capture_output=True, text=True, timeout=600, env=env)
    assert trained.returncode == 0, trained.stderr
    assert (tmp_path / "poly.json").is_file() and str(tmp_path / "poly.json") in trained.stdout
    assert hashlib.sha256(shipped.read_bytes()).hexdigest() == before  # the installed package is never rewritten
    described = subprocess.run([sys.executable, "-m", "railswitch", "describe", "--json"], capture_output=True,
                               text=True, timeout=120, env=env)
    reduced = json.loads(described.stdout)["reduced"]
    assert reduced["poly"]["parameters_file"] == str(tmp_path / "poly.json") and not reduced["poly"]["shipped"]
    assert reduced["nn"]["shipped"]  # the others still come from the package
    assert reduced["poly"]["trained"]["iterations"] == 2
