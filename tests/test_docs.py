"""The API reference (docs/api, `make docs`) builds, and its build fails on what it is there to
catch: a docstring's reference that names nothing, a public name or a module left out.

The build is Sphinx's, with the Makefile's flags (nitpicky, warnings as errors; docs/api/conf.py
says what is checked). It runs here rather than as a line of the Makefile's ``test`` target so that
it runs beside the rest of the suite on pytest-xdist's workers, under ``make test`` and in CI alike,
and reports its warnings as a test failure; ``make docs`` runs the same build by hand.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytest.importorskip("sphinx", reason="Sphinx builds the API reference: pip install -e '.[docs]'")


def sphinx_build(source: Path, out: Path) -> subprocess.CompletedProcess:
    """`make docs`'s build of ``source`` (a docs/api) into ``out``: its flags, read from the
    Makefile so that the two cannot drift apart."""
    flags = re.search(r"^SPHINX := \$\(BIN\)/python -m sphinx (.*)$",
                      (ROOT / "Makefile").read_text(), re.M).group(1).split()
    return subprocess.run([sys.executable, "-m", "sphinx", *flags, str(source), str(out)],
                          capture_output=True, text=True, timeout=600)


def test_the_api_reference_builds_without_a_warning(tmp_path):
    run = sphinx_build(ROOT / "docs" / "api", tmp_path / "html")
    assert run.returncode == 0, f"`make docs` fails:\n{run.stderr}"
    index = (tmp_path / "html" / "index.html").read_text()
    assert 'id="dualarm_mpc.load_scenario"' in index  # a public name, documented at the top


@pytest.mark.slow
def test_a_broken_reference_fails_the_build(tmp_path):
    """In a copy of the package and its docs/api: a docstring refers to a function by its module's
    path of before the move into subpackages, a public name is left out of the top of the
    reference and a module out of its page. Each is an error of the build, named."""
    shutil.copytree(ROOT / "dualarm_mpc", tmp_path / "dualarm_mpc",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "docs" / "api", tmp_path / "docs" / "api")
    verify = tmp_path / "dualarm_mpc" / "model" / "verify.py"
    text = verify.read_text()
    assert ":func:`~dualarm_mpc.model.mld.replay`" in text
    verify.write_text(text.replace(":func:`~dualarm_mpc.model.mld.replay`",
                                   ":func:`~dualarm_mpc.mld.replay`"))
    index = tmp_path / "docs" / "api" / "index.rst"
    index.write_text(index.read_text().replace(".. autofunction:: delivered_objects\n", ""))
    page = tmp_path / "docs" / "api" / "base.rst"
    page.write_text(page.read_text().replace(".. automodule:: dualarm_mpc.base.palette\n", ""))

    run = sphinx_build(tmp_path / "docs" / "api", tmp_path / "html")
    assert run.returncode != 0
    assert str(tmp_path / "dualarm_mpc") in run.stderr  # the copy was documented, not the package
    for error in ("model/verify.py:docstring of dualarm_mpc.model.verify:3: WARNING: py:func "
                  "reference target not found: dualarm_mpc.mld.replay",
                  "public name dualarm_mpc.delivered_objects is not documented",
                  "module dualarm_mpc.base.palette is in no page"):
        assert error in run.stderr, run.stderr
