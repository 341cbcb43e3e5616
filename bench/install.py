"""What installing the package takes: the time and the disk of a fresh venv with it, for the
README's figures (``make demo`` installs the package alone, ``make test`` every extra).

What it measures, per install (the package alone, then each ``--extra``): a new venv in a
temporary folder (``python -m venv``, the Makefile's way, its bundled pip), then ``pip install
<repository>[extra]``, non-editable, from wherever this machine's pip finds packages (its cache,
local wheels, the index: the lines of pip's output that say which, counted) and timed; then the
venv's size on disk (the blocks its files take, as ``du`` counts them, in MB of 10⁶ bytes), its
distributions and its largest ones, whether ``py.typed`` was installed with the package, and
whether ``dualarm-mpc --version`` runs, and the load average at its end (other work slows the
install: the times are this machine's at that load). The venv is removed afterwards.

Run it (from the repository root)::

    .venv/bin/python bench/install.py                  # the package alone
    .venv/bin/python bench/install.py --extra test     # and the test extra (1.5 GB, minutes)

It writes ``bench/results/install.json`` (the installs, the options and the machine);
``bench/report.py`` renders it in README.md.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchlib import fmt, machine, options_json, table, write_json_atomic

ROOT = Path(__file__).resolve().parent.parent

# the Makefile's targets and what they install
TARGETS = {None: "`make demo`", "docs": "`make docs`", "test": "`make test`"}


def disk_bytes(folder: Path) -> int:
    """The bytes ``folder``'s files take on disk (blocks, each hard-linked file once), as ``du``
    counts them."""
    seen, total = set(), 0
    for dirpath, dirnames, filenames in os.walk(folder):
        for name in dirnames + filenames:
            st = os.lstat(os.path.join(dirpath, name))
            if (st.st_dev, st.st_ino) not in seen:
                seen.add((st.st_dev, st.st_ino))
                total += st.st_blocks * 512
    return total


def distributions(python: Path) -> dict[str, str]:
    """Name → version of every distribution in the venv of ``python``."""
    out = subprocess.run([str(python), "-m", "pip", "list", "--format", "json"],
                         capture_output=True, text=True, check=True).stdout
    return {d["name"]: d["version"] for d in json.loads(out)}


def largest(site: Path, n: int = 5) -> list[list]:
    """The ``n`` largest distributions in ``site`` (site-packages): [name, MB], by the files each
    one's RECORD lists (its own, not what it depends on)."""
    sizes = []
    for info in site.glob("*.dist-info"):
        record = info / "RECORD"
        if not record.is_file():
            continue
        total = 0
        for line in record.read_text().splitlines():
            path = site / line.split(",", 1)[0]
            if path.is_file() and not path.is_symlink():
                total += path.stat().st_blocks * 512
        name = info.name.removesuffix(".dist-info").rsplit("-", 1)[0]
        sizes.append([name, round(total / 1e6, 1)])
    return sorted(sizes, key=lambda s: -s[1])[:n]


def sources(pip_output: str) -> dict[str, int]:
    """How many packages pip took from where, by its own lines: downloaded from an index, from
    its cache, or a file on this machine (local wheels, the source tree)."""
    count = {"downloaded": r"^\s*Downloading ", "cached": r"^\s*Using cached ",
             "local_file": r"^\s*Processing "}
    return {k: len(re.findall(p, pip_output, re.M)) for k, p in count.items()}


def install(extra: str | None, work: Path) -> dict:
    """A fresh venv in ``work`` with the package (and ``extra``) installed, measured."""
    venv = work / "venv"
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    venv_s = time.perf_counter() - t0
    python = venv / "bin" / "python"
    requirement = str(ROOT) + (f"[{extra}]" if extra else "")
    t0 = time.perf_counter()
    run = subprocess.run([str(python), "-m", "pip", "install", "--progress-bar", "off",
                          requirement], capture_output=True, text=True)
    install_s = time.perf_counter() - t0
    if run.returncode != 0:
        raise SystemExit(f"pip install {requirement} failed:\n{run.stdout}\n{run.stderr}")
    site = next((venv / "lib").glob("python3*/site-packages"))
    dists = distributions(python)
    version = subprocess.run([str(venv / "bin" / "dualarm-mpc"), "--version"],
                             capture_output=True, text=True)
    return {
        "extra": extra,
        "target": TARGETS.get(extra),
        "command": "pip install ." + (f"[{extra}]" if extra else ""),
        "venv_s": round(venv_s, 1),
        "install_s": round(install_s, 1),
        "size_mb": round(disk_bytes(venv) / 1e6, 1),
        "distributions": len(dists),
        "largest_mb": largest(site),
        "sources": sources(run.stdout),
        "py_typed": (site / "dualarm_mpc" / "py.typed").is_file(),
        "cli_runs": version.returncode == 0,
        "pip": dists.get("pip"),
        "load_avg_1min": round(os.getloadavg()[0], 2),  # the machine's load over the install
    }


def report(data: dict) -> str:
    rows = []
    for r in data["installs"]:
        what = "the package alone" if r["extra"] is None else f"the `{r['extra']}` extra"
        big = ", ".join(f"{name} {mb:.0f}" for name, mb in r["largest_mb"][:3])
        rows.append([f"{r['target'] or '—'}: {what} (`{r['command']}`)",
                     f"{fmt(r['install_s'], '.0f')} s", f"{r['size_mb']:.0f} MB",
                     str(r["distributions"]), big])
    return table(["install (a fresh venv)", "pip install", "venv on disk", "distributions",
                  "largest (MB)"], rows) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--extra", action="append", default=[], choices=["docs", "test"],
                   help="measure the install with this extra too, after the package alone "
                        "(repeatable)")
    p.add_argument("--json", type=Path, default=ROOT / "bench" / "results" / "install.json")
    args = p.parse_args(argv)
    info = machine()
    installs = []
    for extra in [None, *args.extra]:
        work = Path(tempfile.mkdtemp(prefix="dualarm-install-"))
        try:
            installs.append(install(extra, work))
        finally:
            shutil.rmtree(work, ignore_errors=True)
        r = installs[-1]
        print(f"{r['command']}: {r['install_s']:.0f} s, {r['size_mb']:.0f} MB, "
              f"{r['distributions']} distributions", file=sys.stderr)
    data = {"installs": installs, "options": options_json(args), "machine": info}
    write_json_atomic(args.json, data)
    print(report(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())
