"""Tests for model.spec's check of user rules: every rule the planner cannot use is refused
with its field before any solve (issue 7), the paper's rules and sound user rules pass."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from strategies import formulas

from dualarm_mpc.logic.ltl import eta, theta
from dualarm_mpc.logic.transform import nnf
from dualarm_mpc.model.scenario import ScenarioError, load_scenario
from dualarm_mpc.model.spec import MAX_RULE_INSTANCES, negated_atoms, rule_formulas, specification


def _rules(rules: list[str], **overrides):
    return rule_formulas(load_scenario("table1_vc", {"rules": rules, **overrides}))


@pytest.mark.parametrize(
    ("rule", "message"),
    [
        ("G foo", "rules[1]: unknown atom foo: the atoms are eta[i,j]"),
        ("G eta[1,2,3]", "rules[1]: unknown atom eta[1,2,3]"),
        ("G !theta[1]", "rules[1]: theta[1] appears negated"),
        ("G(theta[j] -> WX theta[j]) & !F theta[2]", "rules[1]: theta[2] appears negated"),
        ("G eta[3,1]", "rules[1]: eta[3,1]: the hand is 1 (right), 2 (left) or the placeholder i"),
        ("G !eta[j,1]", "rules[1]: eta[j,1]: the hand is"),
        ("G eta[1,11]", "rules[1]: eta[1,11]: no object 11 (objects 1..10)"),
        ("F theta[0]", "rules[1]: theta[0]: no object 0"),
        ("G !eta[1,i]", "rules[1]: eta[1,i]: i is the hand placeholder"),
    ],
)
def test_a_rule_the_planner_cannot_use_is_refused_by_field(rule: str, message: str) -> None:
    """Before: an unknown atom failed at the first solve (a traceback at every replan of the
    closed loop, while the robot idled)."""
    with pytest.raises(ScenarioError) as info:
        _rules(["G true", rule])
    assert str(info.value).startswith(message), info.value


def test_an_object_s_name_means_that_object_and_a_word_that_is_none_is_refused() -> None:
    """``G !eta[1,object1]`` was a placeholder over every object (arm 1 never held anything),
    and ``G !eta[1,cup]`` with no object cup the same, silently."""
    named = dict(_rules(["G !eta[1,object1] & F theta[object3]"]))
    numbered = dict(_rules(["G !eta[1,1] & F theta[3]"]))
    assert list(named.values())[-1] == list(numbered.values())[-1]
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: eta\[1,cup\]: cup is no object's "
                       r"name and no placeholder \(one letter: j, l, ...\); the objects: "
                       r"object1, object2, .*object10, or their numbers 1..10$"):
        _rules(["G !eta[1,cup]"])
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: eta\[object1,2\]: the hand is"):
        _rules(["G !eta[object1,2]"])  # a name stands for an object, never a hand


def test_more_placeholders_than_a_step_has_objects_is_refused() -> None:
    """It expanded to nothing: the rule was silently dropped."""
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: 3 distinct object placeholders "
                       r"\(a, b, c\) but a sequential step has at most 2 objects \(n_o = 2"):
        _rules(["G(eta[1,a] -> !eta[1,b] & !eta[1,c])"], m_o=2, n_o=2)
    _rules(["G(eta[1,a] -> !eta[1,b] & !eta[1,c])"], m_o=2, n_o=3)


def test_a_rule_whose_expansion_is_huge_is_refused_with_its_size() -> None:
    rule = "G(" + " & ".join(f"eta[i,{p}]" for p in "abcdefg") + ")"
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: expands to 1,209,600 instances "
                       r"\(7 object placeholders over the 10 objects of a step\)"):
        _rules([rule], n_o=10)
    assert 2 * 10 * 9 * 8 * 7 < MAX_RULE_INSTANCES  # four placeholders with i still pass
    _rules(["G(eta[i,a] & eta[i,b] & eta[i,c] -> WX !eta[i,d])"], n_o=10)


@pytest.mark.parametrize("rule", [1, 2])
def test_the_papers_rules_pass_on_one_object(rule: int) -> None:
    """No-swap (20) has two placeholders: over one object it is vacuous, and that is right."""
    s = load_scenario("table1_vc", {"objects": [{"name": "a", "position": [0.1, 0.1],
                                                 "goal": "red"}], "m_o": 1, "n_o": 1,
                                    "rule": rule})
    assert [name for name, _ in rule_formulas(s)]


def test_sound_user_rules_pass_and_expand() -> None:
    named = _rules(["G !eta[2,3]", "G(eta[i,j] -> WX !eta[i,l])", "F(theta[1] | !eta[1,2])"])
    s = load_scenario("table1_vc", {"rules": ["G(eta[i,j] -> WX !eta[i,l])"]})
    spec = specification(s, [0, 1, 2], rules=named)
    assert len(spec.rules) == 5


def test_a_rule_in_spots_or_ltlf2dfas_syntax_is_the_same_rule() -> None:
    ours, spot, ltlf2dfa = (_rules([text])[-1][1] for text in [
        "G(eta[i,j] -> WX !eta[i,l])", "[](eta[i,j] => N ~eta[i,l])",
        "G(eta[i,j] -> WX(!(eta[i,l])))"])
    assert ours == spot == ltlf2dfa


def test_nested_equivalences_count_as_their_negation_normal_form() -> None:
    """nnf writes each argument of <-> twice: 20 nested ones are 2^20 copies of the innermost,
    refused before the encoder would build them."""
    rule = "G(" + "(eta[1,1] <-> " * 20 + "eta[2,1]" + ")" * 21
    with pytest.raises(ScenarioError, match=r"^rules\[0\]: the rules up to this one expand to "
                       r"[0-9,]+ formula nodes"):
        _rules([rule])
    _rules(["G(" + "(eta[1,1] <-> " * 5 + "eta[2,1]" + ")" * 6])


@settings(max_examples=200, deadline=None)
@given(formulas([eta(1, 1), eta(2, 1), theta(1)], max_leaves=10))
def test_negated_atoms_are_those_under_a_not_in_the_negation_normal_form(f) -> None:
    """In nnf(f) a Not stands only on an atom, so there the walk finds exactly those."""
    assert negated_atoms(f) == negated_atoms(nnf(f))
