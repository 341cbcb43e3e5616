"""The command line on a corpus of bad files and flags (``tests/bad_inputs/``), each in its own
process as a user runs it (issue 7): a nonzero exit (2, bad input), a message naming the field,
flag or formula position, no traceback, and done within seconds — the subprocess timeout is the
limit, never a measured time."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # a CLI process per input

CORPUS = Path(__file__).parent / "bad_inputs"
# A bad input is refused before any solve: Python, numpy and pydrake load in about a second.
TIMEOUT_S = 10


def run(*args: str, cwd: Path = CORPUS) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dualarm_mpc.cli.app", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=TIMEOUT_S)


# (arguments, what stderr must name); files are in CORPUS, base.yaml is a good scenario.
CASES = [
    # files
    (["plan", "not_utf8.yaml"], "not_utf8.yaml: not UTF-8 text (byte 9 is 0xe9)"),
    (["plan", "bad_yaml.yaml"], "bad_yaml.yaml:2: not valid YAML"),
    (["plan", "not_a_mapping.yaml"], "expected a mapping of scenario fields"),
    (["plan", "missing.yaml"], "scenario: 'missing.yaml' is neither a file nor one of"),
    (["plan", "unknown_field.yaml"], "goalz: unknown field"),
    (["plan", "text_for_a_number.yaml"], "max_speed: expected a number, got 'fast'"),
    (["plan", "unknown_goal.yaml"], "objects[0].goal: 'purple' is not a goal"),
    (["plan", "no_position.yaml"], "objects[0].position: missing"),
    (["plan", "objects_and_random_objects.yaml"], "objects: given while random_objects"),
    (["plan", "negative_event_time.yaml"], "events[0].time: must be >= 0"),
    (["plan", "negative_seed.yaml"], "seed: must be >= 0"),
    (["plan", "random_count_huge.yaml"], "random_objects.count: must be >= 1 and <= 200"),
    (["plan", "off_table.yaml"], "objects[0].position: a at [0.3, -0.5] lies beyond the hands'"),
    (["plan", "tiny_dt.yaml"], "dt: must be >= 0.01 and <= 10, got 0.0001"),
    (["plan", "deep_yaml.yaml"], "deep_yaml.yaml:5: nested too deeply"),
    # YAML 1.2, read as written (issue 37)
    (["plan", "dup_key.yaml"], "dup_key.yaml:7: duplicate key 'dt' (first at dup_key.yaml:4)"),
    (["plan", "dup_position.yaml"],
     "dup_position.yaml:7: duplicate key 'position' (first at dup_position.yaml:5)"),
    (["plan", "billion_laughs.yaml"], "billion_laughs.yaml:13: more than 1,000,000 characters "
                                      "with its aliases"),
    (["plan", "rule_aliases.yaml"], "rule_aliases.yaml:6: more than 1,000,000 characters"),
    (["plan", "recursive_alias.yaml"], "recursive_alias.yaml:4: an alias inside the node"),
    (["plan", "two_documents.yaml"], "two_documents.yaml:5: not valid YAML: expected a single "
                                     "document"),
    (["plan", "tab_indent.yaml"], "tab_indent.yaml:4: not valid YAML: while scanning for the "
                                  "next token, found character that cannot start any token (a "
                                  "tab: YAML indents with spaces)"),
    (["plan", "base.yaml", "--set", "dt: 1\ndt: 2"], "--set 'dt: 1\\ndt: 2':2: duplicate key"),
    (["plan", "base.yaml", "--set", "[dt, 1]"], "expected a mapping of scenario fields"),
    (["plan", "base.yaml", "--set", "objects[0].goal: null"],
     "objects[0].goal: expected text, got None (quote it to mean the text)"),
    (["plan", "base.yaml", "--set", "seed: 1" + "0" * 5000], ":1: an integer of 5,001 digits"),
    # numbers in their documented ranges (docs/scenarios.md)
    (["plan", "huge_dt.yaml"], "dt: must be >= 0.01 and <= 10, got 1e+308"),
    (["plan", "overflowing_speed.yaml"], "max_speed: expected a finite number, got '99999"),
    (["plan", "base.yaml", "--set", "state_weight: -1"], "state_weight: must be >= 0 and <= 100"),
    (["simulate", "base.yaml", "--set", "solver.replan_budget_s: -0.5"],
     "solver.replan_budget_s: must be >= 0 and <= 3600, got -0.5"),
    (["simulate", "base.yaml", "--set", "object_size: 0.2"], "object_size: must be >= 0.01 and "
                                                             "< 0.2, got 0.2"),
    (["simulate", "base.yaml", "--set", "object_size: 1e-6"], "object_size: must be >= 0.01"),
    (["simulate", "base.yaml", "--set", "slide_time_constant: 1e-6"],
     "slide_time_constant: must be >= 0.01 and <= 1000, got 1e-06"),
    (["plan", "base.yaml", "--set", "objects[1].position: [1e300, 0.1]"],
     "objects[1].position[0]: must be >= -10 and <= 10, got 1e+300"),
    (["plan", "base.yaml", "--set", "solver.threads: 100000"], "solver.threads: must be >= 1 and "
                                                               "<= 64"),
    (["simulate", "base.yaml", "--set", "arm_bases: [[3, -0.8], [-3, -0.8]]"],
     "arm_bases: [[3.0, -0.8], [-3.0, -0.8]] are not the robot model's"),
    (["simulate", "base.yaml", "--set", "workspace: [-3, 3, 0, 3]"],
     "workspace: [-3.0, 3.0, 0.0, 3.0] is not all within reach of arm 1"),
    (["plan", "base.yaml", "--set", "random_objects: {count: 3}"],
     "random_objects: given while the scenario lists 2 objects, which the draw would replace"),
    # rules
    (["plan", "unknown_atom.yaml"], "rules[0]: unknown atom foo"),
    (["simulate", "unknown_atom.yaml"], "rules[0]: unknown atom foo"),
    (["simulate", "negated_goal_atom.yaml"], "rules[0]: theta[1] appears negated"),
    (["plan", "too_many_placeholders.yaml"], "rules[0]: 3 distinct object placeholders"),
    (["plan", "huge_expansion.yaml"], "rules[0]: expands to 1,209,600 instances"),
    (["plan", "deep_parentheses.yaml"], "rules[0]: column 50: nested deeper than 50 levels"),
    (["simulate", "deep_negations.yaml"], "rules[0]: column 50: nested deeper than 50 levels"),
    (["plan", "long_rule_syntax_error.yaml"], "rules[0]: column 1800: expected a formula"),
    # flags
    (["plan", "base.yaml", "--out", "no/such/dir/plan.json"], "argument --out: directory"),
    (["plan", "base.yaml", "--out", "."], "argument --out: . names a directory"),
    (["plan", "base.yaml", "--plot", "plan.xyz"], "argument --plot: unknown plot format 'xyz'"),
    (["simulate", "base.yaml", "--html", "no/such/dir/r.html"], "argument --html: directory"),
    (["simulate", "base.yaml", "--summary", "/proc/s.json"], "argument --summary: cannot write"),
    (["simulate", "base.yaml", "--duration", "0"], "argument --duration: must be a positive"),
    (["simulate", "base.yaml", "--duration", "nan"], "argument --duration: must be a positive"),
    (["simulate", "base.yaml", "--duration", "-1"], "argument --duration: must be a positive"),
    (["plan", "base.yaml", "--seed", "-1"], "argument --seed: must be >= 0"),
    (["plan", "base.yaml", "--mo", "0"], "argument --mo: must be >= 1"),
    (["plan", "base.yaml", "--mo", "every"], "argument --mo: expected an integer or all"),
    (["plan", "base.yaml", "--gap", "2"], "argument --gap: must be between 0 and 1"),
    (["plan", "base.yaml", "--mo", "all", "--no", "3"], "argument --no: not with --mo all"),
    (["plan", "table1_vd", "--mo", "all", "--set", "{random_objects: {count: 14}}"],
     "--mo all (the whole task in one step): 14 objects, more than one step may deliver"),
    (["plan", "base.yaml", "--rule", "3"], "argument --rule: invalid choice"),
    (["plan", "base.yaml", "--time-limit", "-5"], "argument --time-limit: must be a positive"),
    (["plan", "base.yaml", "--set", "max_speed: [1"], "--set 'max_speed: [1':2: not valid YAML"),
    (["plan", "base.yaml", "--set", "solver.timelimit: 3"], "solver.timelimit: unknown field"),
    (["plan", "base.yaml", "--set", "objects[9].goal: red"],
     "objects[9]: no such element (objects has 2)"),
    (["plan", "base.yaml", "--set", "solver.max_horizon: 100000"],
     "solver.max_horizon: must be >= 1 and <= 1000, got 100000"),
    (["check", "base.yaml", "--set", "rules: ['G eta[3,1]']"], "rules[0]: eta[3,1]: the hand"),
]


@pytest.mark.parametrize(("args", "named"), CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_input_is_refused_naming_it(args: list[str], named: str) -> None:
    done = run(*args)
    assert done.returncode == 2, (done.returncode, done.stderr)
    assert named in done.stderr, done.stderr
    assert "Traceback" not in done.stderr + done.stdout


def _scene(tmp_path: Path, objects: int, extra: str = "") -> Path:
    """A scene of ``objects`` objects in a grid on the table, two goals, and ``extra``."""
    rows = [f"  - {{name: o{j}, position: [{-0.3 + 0.6 * (j % 50) / 50:.3f}, "
            f"{0.4 * (j // 50) / 40:.3f}], goal: {'red' if j % 2 else 'blue'}}}"
            for j in range(objects)]
    path = tmp_path / "scene.yaml"
    path.write_text("goals: {red: [0.3, 0.6, 0.6, 0.9], blue: [-0.6, -0.3, 0.6, 0.9]}\n"
                    "objects:\n" + "\n".join(rows) + "\n" + extra)
    return path


# Scenarios too large to keep as files: (objects, extra YAML, what stderr must name)
LARGE = [
    (2000, "m_o: 2\nn_o: 4\n", "objects: 2,000 objects, at most 200"),
    (30, "m_o: 10\nn_o: 30\ntask_form: subsets\n",
     "task_form: subsets makes φ_task a disjunction of 30,045,015 subsets"),
    (2, "m_o: 1\nn_o: 2\nrules: ['" + " & ".join(["eta[1,1]"] * 20_000) + "']\n",
     "rules[0]: 219,997 characters, at most 10,000"),
    (10, "m_o: 2\nn_o: 10\nrules: ['G(" + " | ".join(f"eta[{1 + k % 2},{'jlm'[k % 3]}]"
                                                      for k in range(150)) + ")']\n",
     "rules[0]: the rules up to this one expand to 109,440 formula nodes"),
]


@pytest.mark.parametrize(("objects", "extra", "named"), LARGE, ids=[n[:24] for *_, n in LARGE])
def test_work_beyond_a_cap_is_refused_up_front(tmp_path, objects: int, extra: str,
                                               named: str) -> None:
    done = run("check", str(_scene(tmp_path, objects, extra)), cwd=tmp_path)
    assert done.returncode == 2, (done.returncode, done.stderr)
    assert named in done.stderr, done.stderr
    assert "Traceback" not in done.stderr + done.stdout


def test_a_syntax_error_in_a_long_rule_shows_a_window() -> None:
    """The rule is 3,300 characters long: the message shows a window of it, once."""
    done = run("plan", "long_rule_syntax_error.yaml")
    assert len(done.stderr) < 400, done.stderr


def test_nothing_to_do_exits_zero() -> None:
    done = run("plan", "nothing_to_do.yaml", "--mo", "1")
    assert done.returncode == 0, done.stderr
    assert "nothing to do: every object already rests in its goal" in done.stdout
    assert "Traceback" not in done.stderr + done.stdout


def test_a_plan_prints_no_solver_banner(tmp_path) -> None:
    """HiGHS printed its banner into the step table on the first solve."""
    done = subprocess.run([sys.executable, "-m", "dualarm_mpc.cli.app", "plan",
                           str(CORPUS / "base.yaml")], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "HiGHS" not in done.stdout + done.stderr and "THIRD_PARTY" not in done.stdout
