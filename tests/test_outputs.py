"""Outputs written whole or not at all, stop signals, a closed stdout and the exit-code table
(issue 37), each case in its own process as a user runs it: its exit status, its message, and
that no file was lost or left truncated (the scenario byte for byte as before, every output
either absent or a valid JSON, HTML, PNG or MPS file, no temporary file left). The subprocess
timeout is a limit, never a measured time."""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from scenes import ONE_ON_THE_ROBOT, yaml_text

from dualarm_mpc.base import outputs
from dualarm_mpc.cli.app import main

BASE = Path(__file__).parent / "bad_inputs" / "base.yaml"  # two objects, planned in 0.1 s
LIMIT_S = 120
# A signal to the exit, everything written: about 2 s (plan and its PNG) and 0.5 s (simulate)
# here, idle; the limit, not a measurement.
STOP_S = 10.0


def cli(*args: str, cwd: Path, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "dualarm_mpc.cli.app", *args], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)


def run(*args: str, cwd: Path, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dualarm_mpc.cli.app", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=LIMIT_S, **kwargs)


def stop(proc: subprocess.Popen, sig: int, limit_s: float = STOP_S) -> tuple[str, str]:
    """``sig`` to ``proc``, and its stdout and stderr once it exited, within ``limit_s``."""
    proc.send_signal(sig)
    try:
        return proc.communicate(timeout=limit_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        pytest.fail(f"still running {limit_s:g} s after {signal.Signals(sig).name}")


def whole(path: Path) -> bool:
    """Whether ``path`` is a complete file of its kind."""
    data = path.read_bytes()
    if path.suffix == ".json":
        json.loads(data)
        return True
    if path.suffix == ".html":
        return data.lstrip().lower().startswith(b"<!doctype html") and \
            data.rstrip().endswith(b"</html>")
    if path.suffix == ".png":
        return data.startswith(b"\x89PNG\r\n\x1a\n") and data.endswith(b"IEND\xaeB`\x82")
    if path.suffix == ".mps":
        return data.endswith(b"ENDATA\n")
    raise ValueError(path)


def nothing_lost(directory: Path, scenario: Path, before: bytes) -> None:
    """The scenario as it was; every output in ``directory`` whole; no temporary file left."""
    assert scenario.read_bytes() == before
    for path in directory.rglob("*"):
        assert not path.name.startswith("."), f"left behind: {path}"
        if path.is_file() and path.suffix != ".yaml" and not outputs.same_file(path, scenario):
            assert whole(path), f"{path} is not whole"


@pytest.fixture
def scene(tmp_path) -> tuple[Path, bytes]:
    path = tmp_path / "scenario.yaml"
    shutil.copy(BASE, path)
    return path, path.read_bytes()


# --- refused before any work (exit 2), both flags named ----------------------------------------


def _hard_link(d: Path) -> str:
    os.link(d / "scenario.yaml", d / "hard.yaml")
    return "hard.yaml"


def _symlink(d: Path) -> str:
    (d / "link.json").symlink_to("scenario.yaml")
    return "link.json"


def _loop(d: Path) -> str:
    (d / "a.json").symlink_to("b.json")
    (d / "b.json").symlink_to("a.json")
    return "a.json"


def _fifo(d: Path) -> str:
    os.mkfifo(d / "fifo.json")  # before: opened to test it, which blocked for ever
    return "fifo.json"


def _export_dir(d: Path) -> str:
    (d / "mps").mkdir()
    return "mps"


COLLISIONS = [
    (["plan", "{s}", "--out", "scenario.yaml"], "--out is the scenario file (scenario.yaml)"),
    (["plan", "{s}", "--out", "../{d}/scenario.yaml"], "--out is the scenario file"),
    (["plan", "{s}", "--out", "{hard}"], "--out is the scenario file (hard.yaml)"),
    (["plan", "{s}", "--out", "{symlink}"], "--out is the scenario file (link.json)"),
    (["plan", "{s}", "--out", "p.png", "--plot", "./p.png"],
     "--out and --plot name one file (p.png and ./p.png)"),
    (["simulate", "{s}", "--html", "r.json", "--summary", "r.json"],
     "--html and --summary name one file (r.json)"),
    (["simulate", "{s}", "--summary", "{symlink}"], "--summary is the scenario file (link.json)"),
    (["simulate", "{s}", "--summary", "{symlink}", "--html", "scenario.yaml"],
     "--html and --summary name one file (scenario.yaml and link.json)"),
    (["plan", "{s}", "--export", "{export}", "--out", "mps/index.json"],
     "--out (mps/index.json) is a file --export writes in mps"),
    (["plan", "{s}", "--export", "{export}", "--plot", "mps/step01_T05.mps.png"], None),
    (["plan", "{s}", "--export", "p.json", "--out", "p.json"],
     "--out and --export name one path (p.json)"),
    (["plan", "{s}", "--out", "a.json", "--out", "b.json"], "argument --out: given twice"),
    (["plan", "{s}", "--out", "{fifo}"], "argument --out: fifo.json is a FIFO, not a regular"),
    (["plan", "{s}", "--out", "/dev/full"], "argument --out: /dev/full is a character device"),
    (["plan", "{s}", "--out", "{loop}"], "argument --out: a.json: Too many levels of symbolic"),
    (["plan", "{s}", "--out", "."], "argument --out: . names a directory"),
    (["plan", "{s}", "--out", "new/"], "argument --out: new/ names a directory"),
    (["plan", "{s}", "--out", ""], "argument --out: an empty path"),
    (["plan", "{s}", "--export", "scenario.yaml"], "argument --export: scenario.yaml is not a"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("args", "message"), COLLISIONS)
def test_a_path_that_would_lose_a_file_is_refused_before_any_work(scene, args, message) -> None:
    scenario, before = scene
    d = scenario.parent
    made = {name: make(d) for name, make in (("hard", _hard_link), ("symlink", _symlink),
                                             ("loop", _loop), ("fifo", _fifo),
                                             ("export", _export_dir))
            if f"{{{name}}}" in " ".join(args)}
    files = sorted(d.rglob("*"))
    done = run(*[a.format(s=scenario.name, d=d.name, **made) for a in args], cwd=d)
    if message is None:  # a name the export never writes, in its directory: fine
        assert done.returncode == 0, done.stderr
        assert (d / "mps" / "step01_T05.mps.png").is_file()
    else:
        assert done.returncode == 2, done.stderr
        assert message in done.stderr and "Traceback" not in done.stderr
        assert done.stdout == "" and sorted(d.rglob("*")) == files  # before any work
    nothing_lost(d, scenario, before)


# Root writes anywhere: as root, the run is made without the capabilities that let it.
AS_A_USER = ["setpriv", "--inh-caps=-dac_override,-dac_read_search",
             "--bounding-set=-dac_override,-dac_read_search", "--"] if os.geteuid() == 0 else []


@pytest.mark.slow
@pytest.mark.skipif(bool(AS_A_USER) and not shutil.which("setpriv"),
                    reason="root, and no setpriv to run as a user")
def test_a_read_only_directory_is_refused_before_any_work(scene) -> None:
    scenario, before = scene
    d = scenario.parent
    (d / "ro").mkdir()
    (d / "ro").chmod(0o555)
    try:
        done = subprocess.run([*AS_A_USER, sys.executable, "-m", "dualarm_mpc.cli.app", "plan",
                               scenario.name, "--out", "ro/p.json"], cwd=d, capture_output=True,
                              text=True, timeout=LIMIT_S)
        assert done.returncode == 2, done.stderr
        assert "argument --out: cannot write ro/p.json: Permission denied" in done.stderr
        assert list((d / "ro").iterdir()) == []
    finally:
        (d / "ro").chmod(0o755)
    nothing_lost(d, scenario, before)


# --- a write that fails at the end: one line, exit 4, nothing truncated, the others written ----


def _file_size_limit(size: int):
    return lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))


@pytest.mark.slow
def test_a_plan_over_the_file_size_limit_keeps_the_old_file_whole(scene) -> None:
    scenario, before = scene
    d = scenario.parent
    old = d / "plan.json"
    old.write_text('{"old": true}')
    done = run("plan", scenario.name, "--out", "plan.json", "--export", "mps", cwd=d,
               preexec_fn=_file_size_limit(1000))
    assert done.returncode == 4, done.stderr
    assert "error: cannot write plan.json: File too large" in done.stderr
    assert "error: cannot write mps/step01_T05.mps: File too large" in done.stderr
    assert "Traceback" not in done.stderr
    assert json.loads(old.read_text()) == {"old": True}
    nothing_lost(d, scenario, before)


@pytest.mark.slow
def test_a_failed_plot_leaves_the_plan_json_written(scene) -> None:
    scenario, before = scene
    d = scenario.parent
    done = run("plan", scenario.name, "--out", "plan.json", "--plot", "plan.png", cwd=d,
               preexec_fn=_file_size_limit(20_000))  # the JSON: 4 kB; the PNG: 60 kB
    assert done.returncode == 4, done.stderr
    assert done.stderr.count("error:") == 1
    assert "error: cannot write plan.png: File too large" in done.stderr
    assert "wrote plan.json" in done.stdout and not (d / "plan.png").exists()
    assert json.loads((d / "plan.json").read_text())["verified"] is True
    nothing_lost(d, scenario, before)


@pytest.fixture
def robot(tmp_path) -> tuple[Path, bytes]:
    """One object on the robot: the closed loop in about 7 simulated seconds."""
    path = tmp_path / "robot.yaml"
    path.write_text(yaml_text(ONE_ON_THE_ROBOT))
    return path, path.read_bytes()


@pytest.mark.slow
def test_a_failed_replay_leaves_the_summary_written(robot) -> None:
    scenario, before = robot
    d = scenario.parent
    done = run("simulate", scenario.name, "--html", "replay.html", "--summary", "summary.json",
               cwd=d, preexec_fn=_file_size_limit(200_000))  # the replay: 3 MB
    assert done.returncode == 4, done.stderr
    assert "error: cannot write replay.html: File too large" in done.stderr
    assert "Traceback" not in done.stderr and not (d / "replay.html").exists()
    assert json.loads((d / "summary.json").read_text())["all_delivered"] is True
    nothing_lost(d, scenario, before)


# --- stop signals: what ran is written, marked partial --------------------------------------

SIGNALS = [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)]


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "code"), SIGNALS, ids=lambda v: getattr(v, "name", str(v)))
def test_a_signal_during_a_plan_writes_the_steps_so_far(tmp_path, sig, code) -> None:
    proc = cli("plan", "table1_vd", "--seed", "3", "--out", "plan.json", "--plot", "plan.png",
               cwd=tmp_path)
    for line in proc.stdout:  # the first step's plan (of five): its row of a horizon with a plan
        if {"optimal", "feasible"} & set(line.split()):
            break
    stdout, stderr = stop(proc, sig)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    assert f"interrupted by {sig.name} after" in stderr and "partial" in stderr
    data = json.loads((tmp_path / "plan.json").read_text())
    assert data["partial"] is True and 1 <= len(data["segments"]) < 5
    assert "wrote plan.json (partial)" in stdout and "wrote plan.png (partial)" in stdout
    assert all(whole(p) for p in tmp_path.iterdir())


@pytest.mark.slow
def test_a_stop_sent_twice_to_the_process_group_writes_the_steps_so_far(tmp_path) -> None:
    """Ctrl-C in a shell (and ``timeout``) signals the whole process group, and a key may be
    pressed twice: the repeat is the same stop. Before, it cut the wait for the solver short
    and the steps so far were not written."""
    proc = cli("plan", "table1_vd", "--seed", "3", "--out", "plan.json", cwd=tmp_path,
               start_new_session=True)
    for line in proc.stdout:  # the first step's plan (of five)
        if {"optimal", "feasible"} & set(line.split()):
            break
    os.killpg(proc.pid, signal.SIGINT)
    time.sleep(0.05)
    stdout, stderr = stop(proc, signal.SIGINT)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "terminate called" not in stderr
    assert "interrupted by SIGINT after" in stderr and "partial" in stderr
    assert json.loads((tmp_path / "plan.json").read_text())["partial"] is True


@pytest.mark.slow
@pytest.mark.parametrize(("sig", "code"), SIGNALS, ids=lambda v: getattr(v, "name", str(v)))
def test_a_signal_during_a_simulation_writes_the_summary_and_replay(robot, sig, code) -> None:
    scenario, before = robot
    d = scenario.parent
    proc = cli("simulate", scenario.name, "--summary", "summary.json", "--html", "replay.html",
               cwd=d)
    for line in proc.stdout:  # a replan line: the simulated time in the first column
        if line.split() and line.split()[0].replace(".", "", 1).isdigit():
            break
    stdout, stderr = stop(proc, sig)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr and f"interrupted by {sig.name} at t =" in stderr
    data = json.loads((d / "summary.json").read_text())
    assert data["interrupted"] is True and data["sim_time_s"] > 0
    assert "wrote summary.json (partial)" in stdout and "wrote replay.html (partial;" in stdout
    nothing_lost(d, scenario, before)


@pytest.mark.slow
def test_a_signal_during_the_check_ends_the_run_at_once(tmp_path) -> None:
    """The check of a hundred objects takes a minute; stopped, nothing is kept and the process
    does not wait for the check's solves (within the subprocess timeout)."""
    proc = cli("plan", "table1_vd", "--set", "random_objects.count: 100", "--out", "plan.json",
               cwd=tmp_path)
    assert proc.stdout.readline().startswith("table1_vd: 100 objects")
    time.sleep(2)  # into the check, which takes a minute
    stdout, stderr = stop(proc, signal.SIGTERM)
    assert proc.returncode == 143, stderr
    assert "interrupted by SIGTERM" in stderr and "Traceback" not in stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_a_signal_during_the_largest_step_ends_the_run_at_once(tmp_path) -> None:
    """The largest step a scenario may ask, ten objects delivered of ten: its route bound
    (``route.py``, some 30 s here) polls the stop, so the run ends within the limit with the
    interrupt's exit code (it once ran on for minutes inside the bound)."""
    proc = cli("plan", "table1_vd", "--mo", "10", "--no", "10", cwd=tmp_path)
    for line in proc.stdout:  # the table's head: the first step's bound comes next
        if line.startswith("the horizons T"):
            break
    time.sleep(2)  # into the bound
    stdout, stderr = stop(proc, signal.SIGTERM)
    assert proc.returncode == 143, stderr
    assert "interrupted by SIGTERM" in stderr and "Traceback" not in stderr


# --- a closed stdout does not cost the files ---------------------------------------------------


@pytest.mark.slow
def test_a_closed_stdout_does_not_cost_the_plan(tmp_path) -> None:
    """``dualarm-mpc plan ... --out plan.json | head -1``: before, a BrokenPipeError traceback
    and no plan.json."""
    proc = cli("plan", "table1_vd", "--seed", "3", "--out", "plan.json", cwd=tmp_path)
    assert proc.stdout.readline().startswith("table1_vd:")
    proc.stdout.close()  # head -1 exits: the next line printed meets a closed pipe
    stderr = proc.stderr.read()
    assert proc.wait(timeout=LIMIT_S) == 0, stderr
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr
    data = json.loads((tmp_path / "plan.json").read_text())
    assert data["verified"] is True and not data["partial"]


@pytest.mark.slow
def test_a_stdout_closed_from_the_start_does_not_cost_the_plan(scene) -> None:
    """``dualarm-mpc plan ... >&-``: before, a traceback (Python's sys.stdout is None) and no
    plan.json."""
    scenario, before = scene
    d = scenario.parent
    done = subprocess.run([sys.executable, "-m", "dualarm_mpc.cli.app", "plan", scenario.name,
                           "--out", "plan.json"], cwd=d, stderr=subprocess.PIPE, text=True,
                          timeout=LIMIT_S, preexec_fn=lambda: os.close(1))
    assert done.returncode == 0, done.stderr
    assert json.loads((d / "plan.json").read_text())["verified"] is True
    nothing_lost(d, scenario, before)


def test_a_long_check_says_it_is_still_checking(monkeypatch, capsys) -> None:
    from dualarm_mpc.cli import process
    from dualarm_mpc.planning import consistency

    monkeypatch.setattr(process, "HEARTBEAT_S", 0.0)  # every tick: the line a long check prints
    check = consistency.check

    def slow_check(*args, **kwargs):  # a check longer than a 0.1 s tick
        time.sleep(0.5)
        return check(*args, **kwargs)

    monkeypatch.setattr(consistency, "check", slow_check)
    assert main(["check", str(BASE)]) == 0
    assert "checking the task against the rules: 0 s so far" in capsys.readouterr().out


# --- the exit-code table (cli module docstring, docs/cli.md): each row --------------------------

JOINT_CONFLICT = ["--set", "rules: ['G !eta[2,1]', 'G !eta[2,2]']",  # arm 1 carries both
                  "--set", "solver.max_horizon: 8",  # each alone in 8 steps, both not
                  "--time-limit", "100"]  # each horizon proven infeasible, on a busy machine too
NOTHING_TO_DO = ["--set", "objects: [{name: a, position: [0.3, 0.6], goal: red}]", "--mo", "1",
                 "--no", "1"]
NO_TIME = ["--time-limit", "0.000001"]

EXIT_CODES = [
    (["check", "{s}"], 0, "consistent"),
    # the check leaves the spacing out, and says so
    (["check", "{s}", "--set", "object_clearance: 0.01"], 0,
     "the objects' spacing (object_clearance 0.01 m) is not checked"),
    (["plan", "{s}", "--out", "p.json"], 0, "verified"),
    (["plan", "{s}", *NOTHING_TO_DO, "--plot", "p.png"], 0, "nothing to do"),  # a traceback before
    (["plan", "{s}", "--mo", "0"], 2, "argument --mo: must be >= 1"),
    (["check", "{s}", *JOINT_CONFLICT], 3, "no plan delivers them together"),
    (["plan", "{s}", *JOINT_CONFLICT], 3, "conflict with the task"),
    (["check", "{s}", *NO_TIME], 4, "undecided within the time limit"),
    (["plan", "{s}", *NO_TIME], 4, "not decided within the time limit"),  # 3 before: no proof
    (["simulate", "{r}", "--duration", "1"], 4, "not every object ends at rest"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("args", "code", "message"), EXIT_CODES)
def test_each_exit_code_of_the_table(scene, robot, args, code, message) -> None:
    scenario, before = scene
    d = scenario.parent
    done = run(*[a.replace("{s}", scenario.name).replace("{r}", robot[0].name) for a in args],
               cwd=d)
    assert done.returncode == code, done.stdout + done.stderr
    assert message in done.stdout + done.stderr and "Traceback" not in done.stderr
    nothing_lost(d, scenario, before)


def test_the_table_is_in_the_module_docstring_and_the_docs() -> None:
    import dualarm_mpc.cli.app as cli_module

    docs = (Path(__file__).parents[1] / "docs" / "cli.md").read_text()
    for text in (cli_module.__doc__, docs):
        for code in ("0 ", "2 ", "3 ", "4 ", "129 / 130 / 143"):
            assert f"\n  {code}" in text or f"| {code.strip()} " in text, code


# --- the writer, in-process --------------------------------------------------------------------


def test_a_write_that_fails_leaves_the_old_file_and_no_temporary_one(tmp_path) -> None:
    path = tmp_path / "out.json"
    path.write_text("old")
    path.chmod(0o640)

    def fail(tmp: Path) -> None:
        tmp.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError) as err:
        outputs.write_with(path, fail)
    assert err.value.filename == str(path) and err.value.strerror == "No space left on device"
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.json"]
    outputs.write(path, "new")
    assert path.read_text() == "new" and path.stat().st_mode & 0o777 == 0o640


def test_an_output_keeps_its_error_and_a_symlink_its_target(tmp_path) -> None:
    target = tmp_path / "target.json"
    (tmp_path / "link.json").symlink_to(target.name)
    outputs.write(tmp_path / "link.json", "{}")
    assert (tmp_path / "link.json").is_symlink() and target.read_text() == "{}"
    missing = outputs.Output(str(tmp_path / "gone" / "x.json"), "--out")
    outputs.write(missing, "{}")  # kept, not raised: the run goes on to its other outputs
    assert missing.error is not None and missing.error.filename == missing.path


@pytest.mark.skipif(shutil.which("xelatex") is not None, reason="xelatex installed: PGF works")
def test_a_plot_format_that_cannot_be_written_here_is_refused_before_any_work(capsys) -> None:
    """Before: the plan was made, then matplotlib's traceback (no xelatex for PGF)."""
    with pytest.raises(SystemExit) as exit_:
        main(["plan", str(BASE), "--plot", "plan.pgf"])
    assert exit_.value.code == 2
    assert "argument --plot: plot format 'pgf' needs xelatex" in capsys.readouterr().err


def test_json_outputs_have_no_infinity_or_nan() -> None:
    """RFC 8259 has neither: ``jq`` and most parsers refuse a file with them."""
    data = {"gap": float("inf"), "cost": [1.5, float("nan")], "name": "a"}
    assert json.loads(outputs.json_text(data), parse_constant=pytest.fail) == \
        {"gap": None, "cost": [1.5, None], "name": "a"}


def test_nothing_to_do_with_a_plot_writes_it(tmp_path, capsys) -> None:
    path = tmp_path / "s.yaml"
    shutil.copy(BASE, path)
    png = tmp_path / "p.png"
    assert main(["plan", str(path), *NOTHING_TO_DO, "--plot", str(png)]) == 0
    assert whole(png)


def test_a_path_is_judged_as_the_os_would_open_it(tmp_path, monkeypatch, capsys) -> None:
    """``p.json/.`` and ``x/../p.json`` (no x) were written as ./p.json, and a link to a file in
    a missing directory named the wrong directory (issue 52)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "link.json").symlink_to("gone/deeper/p.json")
    cases = {"p.json/.": "p.json/. names a directory",
             "p.json/..": "p.json/.. names a directory",
             "x/../p.json": "directory x does not exist",
             "a/b/../../p.json": "directory a does not exist",
             "link.json": "link.json is a symbolic link to gone/deeper/p.json, and directory "
                          f"{tmp_path / 'gone'} does not exist"}
    for path, said in cases.items():
        assert outputs.output_problem(path) == said
        with pytest.raises(SystemExit):
            main(["plan", str(BASE), "--out", path])
        assert f"argument --out: {said}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.json"]


def test_a_signal_between_two_outputs_says_which_were_written(tmp_path, monkeypatch,
                                                              capsys) -> None:
    """A stop after plan.json is written but before plan.png said only "interrupted by
    SIGINT" (issue 52). The signal is raised where the plot is drawn, as Ctrl-C there would."""
    from dualarm_mpc.figures import plan as figure

    def signalled(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(figure, "plot_plan", signalled)
    assert main(["plan", str(BASE), "--out", "p.json", "--plot", "p.png"]) == 130
    assert "interrupted by SIGINT; wrote p.json; not written: p.png" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.json"]
    assert whole(tmp_path / "p.json")
