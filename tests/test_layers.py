"""The layer contracts of pyproject.toml ([tool.importlinter]): the data flows one way through the rooms.

import-linter reads a package from where Python finds it, and the editable
install maps the top-level ``plugins/`` to ``mi_nest.plugins`` through an
import hook that its module scan does not follow: the package is laid out as a
wheel installs it, in a temporary directory, and checked there.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECK = ("import sys; from importlinter.cli import lint_imports; "
         "sys.exit(lint_imports(config_filename=sys.argv[1], no_cache=True, no_logo=True))")


def installed_layout(directory: Path) -> Path:
    """``mi_nest`` with ``plugins/`` inside it, as setup.py installs them, under ``directory``."""
    skip = shutil.ignore_patterns("__pycache__")
    shutil.copytree(ROOT / "mi_nest", directory / "mi_nest", ignore=skip)
    shutil.copytree(ROOT / "plugins", directory / "mi_nest" / "plugins", ignore=skip)
    return directory


def test_the_layer_contracts_hold(tmp_path):
    # Run where the copy comes first on sys.path: in this process ``mi_nest`` is the editable install.
    result = subprocess.run([sys.executable, "-c", CHECK, str(ROOT / "pyproject.toml")],
                            cwd=installed_layout(tmp_path), capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout
