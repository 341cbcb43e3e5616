"""The tutorial notebook (examples/tutorial.ipynb) is committed clean, uses only the public API,
and runs: executed as a user would, in a fresh kernel of this interpreter, in a working
directory of its own, it checks, plans, simulates, and the robot delivers what it says."""

from __future__ import annotations

import ast
import json
import re
import sys
import time
from pathlib import Path

import pytest

import dualarm_mpc as dm

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "tutorial.ipynb"


def code_cells() -> list[str]:
    cells = json.loads(NOTEBOOK.read_text(encoding="utf-8"))["cells"]
    return ["".join(c["source"]) for c in cells if c["cell_type"] == "code"]


def as_python(cell: str) -> str:
    """A cell as the kernel runs it: IPython magics (``%matplotlib inline``) become calls."""
    from IPython.core.inputtransformer2 import TransformerManager

    return TransformerManager().transform_cell(cell)


def test_the_notebook_is_committed_without_outputs() -> None:
    cells = json.loads(NOTEBOOK.read_text(encoding="utf-8"))["cells"]
    code = [c for c in cells if c["cell_type"] == "code"]
    assert code and all(c["outputs"] == [] and c["execution_count"] is None for c in code)
    assert NOTEBOOK.stat().st_size < 50_000


def test_the_notebook_uses_only_the_public_api() -> None:
    """The package is imported once, as ``dm``, and only its public names are used."""
    imports, names = [], set()
    for cell in code_cells():
        for node in ast.walk(ast.parse(as_python(cell))):
            if isinstance(node, ast.Import):
                imports += [(a.name, a.asname) for a in node.names
                            if a.name.split(".")[0] == "dualarm_mpc"]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("dualarm_mpc"):
                imports.append((node.module, "from"))
            elif (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                  and node.value.id == "dm"):
                names.add(node.attr)
    assert imports == [("dualarm_mpc", "dm")]
    assert names and names <= set(dm.__all__), names - set(dm.__all__)


def stream_text(cell) -> str:
    return "".join(o.get("text", "") for o in cell.get("outputs", [])
                   if o["output_type"] == "stream" and o.get("name") == "stdout")


@pytest.mark.slow
def test_the_notebook_runs_and_the_robot_delivers(tmp_path, monkeypatch) -> None:
    import nbclient
    import nbformat

    # A kernel spec of this very interpreter, found first (JUPYTER_PATH comes before the user's
    # and the system's kernels), so that the notebook runs in the environment under test.
    spec = tmp_path / "jupyter" / "kernels" / "dualarm-mpc-test"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "dualarm_mpc (tests)", "language": "python"}))
    monkeypatch.setenv("JUPYTER_PATH", str(tmp_path / "jupyter"))
    run = tmp_path / "run"
    run.mkdir()

    nb = nbformat.read(NOTEBOOK, as_version=4)
    started = time.perf_counter()
    nbclient.NotebookClient(nb, kernel_name="dualarm-mpc-test", timeout=600,
                            resources={"metadata": {"path": str(run)}}).execute()
    print(f"the notebook ran in {time.perf_counter() - started:.0f} s")
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
    text = "\n".join(stream_text(c) for c in code)

    # The rule's check: consistent; with the right arm barred too, a conflict naming both rules.
    assert "consistent: True" in text and "consistent: False" in text
    conflict = re.search(r"conflict: objects \('(\w+)',\), rules \((.*)\)", text)
    assert conflict, text
    assert "G !eta[2," in conflict[2] and "G !eta[1," in conflict[2]
    assert "refused:" in text
    # The plan is verified and the left arm never held a red object.
    assert "verified: True" in text
    held = re.search(r"the left arm held objects \[(.*)\]; the red ones are \[(.+)\]", text)
    assert held, text
    left, red = ({int(j) for j in s.split(",") if j.strip()} for s in held.groups())
    assert red and not left & red
    # The plan figure is drawn inline.
    assert any("image/png" in o.get("data", {}) for c in code for o in c.outputs)
    # The replay is written under out/ where the notebook ran, and shown as a frame of the file.
    replay = run / "out" / "replay.html"
    assert replay.stat().st_size > 100_000
    assert any("out/replay.html" in o.get("data", {}).get("text/html", "")
               for c in code for o in c.outputs)
    # The physical outcome: both boxes at rest in their goals.
    assert "delivered 2/2; all_delivered: True" in text
    assert "NOT in its goal" not in text
