"""bench/report.py: the committed benchmark tables are what the committed records give."""

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
REPORT = ROOT / "bench" / "report.py"


def report(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(REPORT), *args], capture_output=True, text=True,
                          timeout=120)


def test_committed_tables_equal_the_records():
    run = report("--check")
    assert run.returncode == 0, run.stderr + "\nrun `python bench/report.py` and commit"


def copy_of_repository(tmp_path: Path) -> Path:
    shutil.copy(ROOT / "README.md", tmp_path / "README.md")
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    shutil.copytree(ROOT / "bench" / "results", tmp_path / "bench" / "results")
    return tmp_path


def test_a_table_edited_by_hand_is_found_and_rewritten(tmp_path):
    root = copy_of_repository(tmp_path)
    readme = root / "README.md"
    committed = readme.read_text()
    lines = committed.splitlines(keepends=True)
    row = next(i for i, line in enumerate(lines) if line.startswith("| (2,5) | 1 |"))
    cells = lines[row].split(" | ")
    cells[4] = "1.000"  # our mean cost
    readme.write_text("".join(lines[:row] + [" | ".join(cells)] + lines[row + 1:]))
    check = report("--check", "--root", str(root))
    assert check.returncode == 1 and "README.md: differs from the records" in check.stderr
    assert report("--root", str(root)).returncode == 0
    assert readme.read_text() == committed


def test_a_marker_naming_no_record_is_one_line_and_exit_2(tmp_path):
    root = copy_of_repository(tmp_path)
    doc = root / "docs" / "benchmarks.md"
    doc.write_text(doc.read_text() + "\n<!-- report table2-none.json -->\n<!-- /report -->\n")
    run = report("--check", "--root", str(root))
    assert run.returncode == 2
    assert run.stderr.strip().splitlines() == [
        f"error: {root / 'bench' / 'results' / 'table2-none.json'}: no such record (a marker "
        "names it)"]
