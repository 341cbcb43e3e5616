"""Specifications: φ_task (eq. 13), the common-sense rules (18)–(20) and user rules, as LTL.

Everything here is a formula: rules are written in the text syntax with placeholders (``i`` ranges
over the arms, any other placeholder over the objects of the sequential step, distinct placeholders
taking distinct objects) and expanded to the objects at hand. The encoder and the evaluator both
consume these same formulas. Atoms: ``eta[i,j]`` — hand i (1 = right, 2 = left) grabs object j;
``theta[j]`` — object j is in its goal; j is the scenario's 1-based object number.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

from dualarm_mpc.ltl import (
    Always,
    Eventually,
    Formula,
    conj,
    disj,
    parse,
    placeholders,
    substitute,
    theta,
)
from dualarm_mpc.scenario import Scenario

ARMS = (1, 2)
ARM_PLACEHOLDER = "i"

# The paper's rules, §V-B, with weak next (design §2: □(θ → ○θ) reads θ(k) → θ(k+1) for k < T).
RULE_TEXT = {
    # (18), and in the goal one step later too: in our object model (design §1) a released
    # object slides one more step, so θ at the release step alone would still allow a throw.
    "no-throw (18)": "G(eta[i,j] & WX !eta[i,j] -> WX theta[j] & WX WX theta[j])",
    "no-juggle (19)": "G((eta[1,j] -> WX !eta[2,j]) & (eta[2,j] -> WX !eta[1,j]))",
    "no-swap (20)": "G(eta[i,j] -> WX !eta[i,l])",
}
RULES = {1: ("no-throw (18)",), 2: ("no-juggle (19)", "no-swap (20)")}


def expand(rule: Formula, objects: list[int]) -> Formula:
    """The conjunction of ``rule`` over every assignment of its placeholders: ``i`` over the arms,
    the others over distinct ``objects`` (1-based scenario numbers)."""
    names = sorted(placeholders(rule))
    object_names = [n for n in names if n != ARM_PLACEHOLDER]
    arm_values = ARMS if ARM_PLACEHOLDER in names else (None,)
    instances = []
    for arm in arm_values:
        for values in itertools.permutations(objects, len(object_names)):
            mapping = dict(zip(object_names, values, strict=True))
            if arm is not None:
                mapping[ARM_PLACEHOLDER] = arm
            instances.append(substitute(rule, mapping))
    return conj(instances)


def delivered(j: int, delivery: str) -> Formula:
    """"Object j is delivered": ◇θ_j (``reach``, the paper) or ◇□θ_j (``rest``: in the goal at the
    horizon's last step, where the model holds every object at rest)."""
    return Eventually(theta(j)) if delivery == "reach" else Eventually(Always(theta(j)))


@dataclass(frozen=True)
class Specification:
    """φ = φ_task ∧ rules for one sequential step over ``objects`` (scenario indices, 0-based)."""

    objects: tuple[int, ...]
    m_o: int
    delivery: str
    task_form: str  # "counting" or "subsets"
    rules: tuple[tuple[str, Formula], ...]  # (name, expanded formula)
    # The objects whose delivery counts towards m_o; all of ``objects`` unless the skeleton
    # search fixes which ones are delivered.
    targets: tuple[int, ...] | None = None

    @property
    def events(self) -> list[Formula]:
        """The ev_j of eq. (13), one per object of the step."""
        targets = self.objects if self.targets is None else self.targets
        return [delivered(j + 1, self.delivery) for j in targets]

    def task(self) -> Formula:
        """φ_task, eq. (13) literally: any m_o of the n_o objects delivered."""
        ev = self.events
        return disj(conj(c) for c in itertools.combinations(ev, self.m_o))

    def formula(self) -> Formula:
        """The whole specification as one formula (eq. 21)."""
        return conj([self.task()] + [f for _, f in self.rules])


def rule_formulas(scenario: Scenario, rule: int | None = None) -> list[tuple[str, Formula]]:
    """The named rules in force (unexpanded): the paper's rule 1 or 2 plus the scenario's own."""
    rule = scenario.rule if rule is None else rule
    named = [(name, parse(RULE_TEXT[name])) for name in RULES[rule]]
    for n, text in enumerate(scenario.rules):
        named.append((f"rules[{n}] {text}", parse(text)))
    return named


def specification(scenario: Scenario, objects: list[int], m_o: int | None = None,
                  rules: list[tuple[str, Formula]] | None = None) -> Specification:
    """The specification of one sequential step over ``objects`` (0-based scenario indices)."""
    m_o = min(scenario.m_o if m_o is None else m_o, len(objects))
    named = rule_formulas(scenario) if rules is None else rules
    numbers = [j + 1 for j in objects]
    return Specification(
        objects=tuple(objects),
        m_o=m_o,
        delivery=scenario.delivery,
        task_form=scenario.task_form,
        rules=tuple((name, expand(f, numbers)) for name, f in named),
    )

