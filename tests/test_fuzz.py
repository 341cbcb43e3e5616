"""Fuzzing the two readers of user text (issue 7): the LTL parser and the scenario loader get random
and mutated input, and only their typed errors may escape — LTLSyntaxError from the parser,
ScenarioError from the loader (and from the check of the rules of a scenario it accepted)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from strategies import formulas

from dualarm_mpc.logic.ltl import Atom
from dualarm_mpc.logic.parser import LTLSyntaxError, parse
from dualarm_mpc.model.scenario import (
    YAML_FIELDS,
    Event,
    ObjectSpec,
    RandomObjects,
    ScenarioError,
    SolverSettings,
    load_scenario,
    scenario_path,
)
from dualarm_mpc.model.spec import rule_formulas

# Each test draws a few hundred inputs; the deadline is off: these tests are about what escapes,
# never about time.
FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

TOKENS = ["(", ")", "[", "]", ",", "&", "|", "!", "~", "->", "-", ">", "X", "WX", "N", "G", "F",
          "U", "R", "true", "false", "eta", "theta", "i", "j", "1", "2", "0", "99999999999999999",
          " ", "\t", "\n", "$", "é", "\u00a0", "p", "eta[1,2]", "theta[j]",
          # Spot's and ltlf2dfa's spellings (docs/ltl.md)
          "<->", "<=>", "=>", "-->", "xor", "^", "W", "M", "V", "[]", "<>", "&&", "||", "/\\",
          "\\/", "X[!]", "X[2]", "F[1:3]", "G[0:$]", "F[2..", ":", "..", "!]", "last", "TRUE",
          "GF", "Xa", '"', '"eta[1,2]"', '"Xa"']


def _parses_or_syntax_error(text: str) -> None:
    try:
        f = parse(text)
    except LTLSyntaxError as err:
        assert 0 <= err.position <= len(text) and err.text == text
        return
    assert parse(str(f)) == f


@FUZZ
@given(st.text(max_size=200))
def test_parser_on_random_text(text: str) -> None:
    _parses_or_syntax_error(text)


@FUZZ
@given(st.lists(st.sampled_from(TOKENS), max_size=400).map(" ".join))
def test_parser_on_token_soup(text: str) -> None:
    """Long runs of ( ! G X or -> reach the nesting limit: a syntax error, no RecursionError."""
    _parses_or_syntax_error(text)


ATOMS = [Atom("eta", (1, 2)), Atom("eta", ("i", "j")), Atom("theta", ("j",)), Atom("theta", (3,))]


@st.composite
def mutated(draw, texts: st.SearchStrategy[str]) -> str:
    """``texts`` with a few characters deleted, inserted, replaced or a span repeated."""
    text = draw(texts)
    for _ in range(draw(st.integers(1, 4))):
        at = draw(st.integers(0, len(text)))
        kind = draw(st.sampled_from(["delete", "insert", "replace", "repeat"]))
        piece = draw(st.sampled_from(TOKENS + list("{}:'\"#-*&!|>%@`0.5e-3")))
        if kind == "delete":
            text = text[:at] + text[at + 1:]
        elif kind == "insert":
            text = text[:at] + piece + text[at:]
        elif kind == "replace":
            text = text[:at] + piece + text[at + 1:]
        else:
            span = text[at:at + draw(st.integers(1, 20))]
            text = text[:at] + span * draw(st.integers(2, 80)) + text[at:]
    return text


@FUZZ
@given(mutated(formulas(ATOMS, max_leaves=10).map(str)))
def test_parser_on_mutated_formulas(text: str) -> None:
    _parses_or_syntax_error(text)


# --- the scenario loader --------------------------------------------------------------------------


def _loads_or_scenario_error(name: str, overrides=None) -> None:
    try:
        scenario = load_scenario(name, overrides)
        rule_formulas(scenario)
    except ScenarioError as err:
        assert str(err)


def _load_file(content: bytes) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "fuzz.yaml"
        path.write_bytes(content)
        _loads_or_scenario_error(str(path))


VC = Path(scenario_path("table1_vc")).read_text()
VD = Path(scenario_path("table1_vd")).read_text()


@FUZZ
@given(st.binary(max_size=300))
def test_loader_on_random_bytes(content: bytes) -> None:
    _load_file(content)


@FUZZ
@given(mutated(st.sampled_from([VC, VD])))
def test_loader_on_mutated_files(text: str) -> None:
    _load_file(text.encode())


@FUZZ
@given(mutated(st.sampled_from([VC, VD])).map(lambda t: t.encode()
                                              [: len(t) // 2] + b"\xff\xfe"))
def test_loader_on_truncated_files_with_bad_bytes(content: bytes) -> None:
    _load_file(content)


def _fields(cls) -> list[str]:
    return list(cls.__dataclass_fields__)


# Keys: the fields, nested fields and paths into lists, and some that are none of these.
KEYS = (list(YAML_FIELDS) + [f"solver.{k}" for k in _fields(SolverSettings)]
        + [f"random_objects.{k}" for k in _fields(RandomObjects)]
        + [f"objects[{n}].{k}" for n in (0, 3, 12) for k in _fields(ObjectSpec)]
        + [f"events[0].{k}" for k in _fields(Event)]
        + ["goals.red", "goals.red[2]", "hand_start[1][0]", "workspace[3]", "objects[0]",
           "solver..x", "x.y", "objects[-1].goal", "rules[0]"])
SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 12), st.integers(), st.floats(),
    st.floats(-2, 2), st.sampled_from(["red", "green", "blue", "object1", "move_goal",
                                       "move_object", "reach", "rest", "skeleton", "1e-3",
                                       "G !eta[2,3]", "G(eta[i,j] -> WX !eta[i,l])", "F foo",
                                       "G !theta[1]", "(" * 60 + "true" + ")" * 60]),
    st.text(max_size=10),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(st.lists(inner, max_size=5),
                            st.dictionaries(st.sampled_from(KEYS + ["name", "position", "goal",
                                                                    "time", "kind", "target"]),
                                            inner, max_size=4)),
    max_leaves=12,
)


@FUZZ
@given(st.sampled_from(["table1_vc", "table1_vd"]),
       st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=5))
def test_loader_on_random_overrides(name: str, overrides: dict) -> None:
    _loads_or_scenario_error(name, overrides)


@FUZZ
@given(st.sampled_from(["table1_vc", "table1_vd"]),
       mutated(st.sampled_from(["solver.time_limit_s: 5", "objects[2].position: [0.1, 0.2]",
                                "rules: ['G(eta[i,j] -> WX !eta[i,l])']", "goals.red[3]: 1.5",
                                "random_objects: {count: 3, min_separation: 0.1}", "seed: 4",
                                "events: [{time: 1, target: object1, position: [0, 0.1]}]"])))
def test_loader_on_mutated_override_text(name: str, text: str) -> None:
    _loads_or_scenario_error(name, text)
