"""Specifications: φ_task (eq. 13), the common-sense rules (18)–(20) and user rules, as LTL.

Everything here is a formula: rules are written in the text syntax with placeholders (``i`` ranges
over the arms, any other placeholder over the objects of the sequential step, distinct placeholders
taking distinct objects) and expanded to the objects at hand. The encoder and the evaluator both
consume these same formulas. Atoms: ``eta[i,j]`` — hand i (1 = right, 2 = left) grabs object j;
``theta[j]`` — object j is in its goal; j is the scenario's 1-based object number. The skeleton
search's relaxations of a specification (which objects a plan may leave untouched, the rule
instances a bound keeps) are here too: they are statements about the rules, not about the search.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, replace

from dualarm_mpc.logic.evaluate import evaluate
from dualarm_mpc.logic.ltl import (
    TRUE,
    Always,
    And,
    Atom,
    Const,
    Equiv,
    Eventually,
    Formula,
    Implies,
    Next,
    Not,
    Or,
    Release,
    StrongRelease,
    Until,
    WeakNext,
    WeakUntil,
    Xor,
    conj,
    disj,
    theta,
)
from dualarm_mpc.logic.parser import parse
from dualarm_mpc.logic.transform import atoms, nnf, partial, placeholders, rename_atoms, substitute
from dualarm_mpc.logic.transform import size as formula_size
from dualarm_mpc.model.mld import State
from dualarm_mpc.model.scenario import Scenario, ScenarioError

ARMS = (1, 2)
ARM_PLACEHOLDER = "i"
# Instances of one rule in a step (arms × ordered choices of objects), beyond which it is refused:
# 4 object placeholders over 10 objects, with i, encode in about 2 s per program; 7 would not fit
# in memory.
MAX_RULE_INSTANCES = 20_000
# Nodes of the user rules once expanded over a step's objects, together, times the steps of the
# largest horizon: the encoder makes a truth value per node and step. The four placeholders above
# make 90,720 nodes; 109,440 took 18 s per program at T = 40 (measured, `check`), more than the
# solve. The cap is 100,000 nodes at the default horizon of 40 (41 steps).
MAX_RULE_NODE_STEPS = 4_100_000

# The paper's rules, §V-B, with weak next (docs/ltl.md: □(θ → ○θ) reads θ(k) → θ(k+1) for k < T).
RULE_TEXT = {
    # (18), and in the goal one step later too: a released object slides one more step (docs/
    # model.md, "The one-step slide"), so θ at the release step alone would still allow a throw.
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
    return conj(dict.fromkeys(instances))  # an instance given twice constrains once


def instances(formula: Formula) -> tuple[Formula, ...]:
    """The top-level conjuncts of an expanded rule (one per placeholder assignment)."""
    return formula.args if isinstance(formula, And) else (formula,)


def delivery_event(j: int, delivery: str) -> Formula:
    """ev_j of eq. (13), "object j is delivered": ◇θ_j (``reach``, the paper) or ◇□θ_j
    (``rest``: in the goal at the horizon's last step, where the model holds every object at
    rest)."""
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
        return [delivery_event(j + 1, self.delivery) for j in targets]

    def task(self) -> Formula:
        """φ_task, eq. (13) literally: any m_o of the n_o objects delivered."""
        ev = self.events
        return disj(conj(c) for c in itertools.combinations(ev, self.m_o))

    def formula(self) -> Formula:
        """The whole specification as one formula (eq. 21)."""
        return conj([self.task()] + [f for _, f in self.rules])

    def released_only_in_goal(self) -> frozenset[int]:
        """The objects (scenario indices) for which no-throw (18) is in force for both arms:
        every release puts them in their goal (the route bound, ``route.py``, relies on it)."""
        return self.kept_by("no-throw (18)")

    def no_throw_for_all(self) -> bool:
        """Whether no-throw (18) is in force for every object of the step."""
        return self.released_only_in_goal() == frozenset(self.objects)

    def kept_by(self, rule_name: str) -> frozenset[int]:
        """The objects (scenario indices) j of the step for which the paper's rule ``rule_name``
        (a key of ``RULE_TEXT``) is in force for both arms, each other object of the step in
        its placeholder l: no-swap (20) for j, say, keeps a hand that lets go of j from taking
        any other object the next step (the band bound, ``band.py``, relies on it)."""
        have = {inst for _, f in self.rules for inst in instances(f)}
        rule = parse(RULE_TEXT[rule_name])
        # TRUE: no instance at all (no-swap for the step's only object), which holds already
        return frozenset(j for j in self.objects if set(instances(expand(
            substitute(rule, {"j": j + 1}), [k + 1 for k in self.objects if k != j]))) <=
            have | {TRUE})

    def monotone_in_horizon(self) -> bool:
        """Whether a plan of horizon T stays one of horizon T + 1 when the robot idles one more
        step (every plan ends at rest, so the model allows it): then feasibility is monotone in
        T and the optimal cost never grows with it, so one check at the largest horizon
        decides whether any horizon has a plan. True when every formula survives repeating its
        trace's last state (:func:`survives_idling`); the paper's rules do."""
        return all(survives_idling(f) for f in self.events + [f for _, f in self.rules])


@dataclass(frozen=True)
class StepProblem:
    """The problem of one sequential step, Algorithm 1 line 3 ("system, variables, LTL of a
    step"): the ``scenario`` (the system: the robot, the goals, the solver's settings), the
    ``state`` the step starts from (over all objects) and the step's specification ``spec``
    (its objects, m_o and rules). What the horizon's MILP (``horizon.HorizonProgram``), the
    skeleton search and the planner of a step are given, as one value."""

    scenario: Scenario
    state: State
    spec: Specification

    def with_spec(self, spec: Specification) -> StepProblem:
        """The same step from the same state, under ``spec`` (a restriction or relaxation of
        this one's: ``with_no_throw``, ``confined``, ``restricted``, fewer rules)."""
        return replace(self, spec=spec)


MAX_IDLING_TRACES = 20_000  # short traces enumerated per rule instance; beyond, "not known"


def survives_idling(formula: Formula) -> bool:
    """Whether ``w ⊨ φ`` implies ``w·w_T ⊨ φ`` for every finite trace w (w_T its last state).

    Repeating the last state changes nothing at steps that cannot see the end; only X and WX
    (WX a is vacuously true at T, a at T + 1 afterwards) can change a value near it. Every
    argument of G, F, U, R (and the root) is therefore checked on every short trace u — as long
    as its nesting of X/WX plus one, over the states of its atoms that eqs. (14)–(15) allow —
    against u with its last state repeated; longer traces follow by induction over those
    arguments (G, F, U, R only grow with the added step when their arguments do). Conjuncts
    (the instances of an expanded rule) are checked one by one; a formula too large to
    enumerate is "not known" (False)."""
    f = nnf(formula)
    if isinstance(f, And):
        return all(survives_idling(a) for a in f.args)
    return _survives_idling(_renumbered(f))


def _renumbered(f: Formula) -> Formula:
    """``f`` with its objects numbered 1, 2, … in their order: whether a formula survives
    idling does not depend on which objects it is about, so the instances of one rule over
    different objects share one enumeration (cached)."""
    found = atoms(f)
    number = {j: n + 1 for n, j in enumerate(sorted({a.index[-1] for a in found}, key=str))}
    return rename_atoms(f, {a: Atom(a.name, (*a.index[:-1], number[a.index[-1]]))
                            for a in found})


@functools.cache
def _survives_idling(f: Formula) -> bool:
    states = list(_grasp_states(sorted(atoms(f), key=str)))
    for g in _temporal_arguments(f) | {f}:
        depth = _next_depth(g)
        if sum(len(states) ** n for n in range(1, depth + 2)) > MAX_IDLING_TRACES:
            return False
        for n in range(1, depth + 2):
            for trace in itertools.product(states, repeat=n):
                u = {a: [st[a] for st in trace] for a in states[0]} if states[0] else {}
                longer = {a: v + v[-1:] for a, v in u.items()}
                if evaluate(g, u, n - 1) and not evaluate(g, longer, n):
                    return False
    return True


def _next_depth(f: Formula) -> int:
    """The deepest nesting of X and WX in ``f``."""
    if isinstance(f, Next | WeakNext):
        return 1 + _next_depth(f.arg)
    if isinstance(f, Always | Eventually | Not):
        return _next_depth(f.arg)
    if isinstance(f, Until | Release):
        return max(_next_depth(f.lhs), _next_depth(f.rhs))
    if isinstance(f, And | Or):
        return max(_next_depth(a) for a in f.args)
    return 0


def _temporal_arguments(f: Formula) -> set[Formula]:
    out: set[Formula] = set()
    stack = [f]
    while stack:
        g = stack.pop()
        if isinstance(g, Always | Eventually):
            out.add(g.arg)
            stack.append(g.arg)
        elif isinstance(g, Next | WeakNext):
            stack.append(g.arg)
        elif isinstance(g, Until | Release):
            out |= {g.lhs, g.rhs}
            stack += [g.lhs, g.rhs]
        elif isinstance(g, And | Or):
            stack += list(g.args)
        elif isinstance(g, Not):
            stack.append(g.arg)
    return out


def _grasp_states(found: list[Atom]):
    """Every truth assignment of ``found`` in which no object is held by two hands (14) and no
    hand holds two objects (15)."""
    for values in itertools.product((False, True), repeat=len(found)):
        sigma = dict(zip(found, values, strict=True))
        held = [a.index for a, v in sigma.items() if v and a.name == "eta" and len(a.index) == 2]
        hands = [i for i, _ in held]
        objects = [j for _, j in held]
        if len(set(hands)) == len(hands) and len(set(objects)) == len(objects):
            yield sigma


def rule_formulas(scenario: Scenario, rule: int | None = None) -> list[tuple[str, Formula]]:
    """The named rules in force (unexpanded): the paper's rule 1 or 2 plus the scenario's own,
    each checked (:func:`check_rule`) before any solve."""
    rule = scenario.task.rule if rule is None else rule
    named = [(name, parse(RULE_TEXT[name])) for name in RULES[rule]]
    seen, nodes, steps = set(), 0, scenario.solver.max_horizon + 1
    for n, text in enumerate(scenario.task.rules):
        f = by_number(parse(text), scenario)
        nodes += check_rule(f, scenario, f"rules[{n}]")
        if nodes * steps > MAX_RULE_NODE_STEPS:
            raise ScenarioError(
                f"rules[{n}]: the rules up to this one expand to {nodes:,} formula nodes over the "
                f"objects of a step, {nodes * steps:,} over the {steps} steps of "
                f"solver.max_horizon, more than {MAX_RULE_NODE_STEPS:,}; use fewer or shorter "
                "rules, fewer placeholders, a smaller n_o or solver.max_horizon")
        if f not in seen:  # a rule given twice is in force once
            seen.add(f)
            named.append((f"rules[{n}] {text}", f))
    return named


def by_number(f: Formula, scenario: Scenario) -> Formula:
    """``f`` with each object index that is an object's name (``eta[1,cup]``, ``theta[cup]``)
    replaced by that object's number: a name means its object, never a placeholder."""
    numbers = {o.name: j + 1 for j, o in enumerate(scenario.task.objects)}
    return rename_atoms(f, {a: Atom(a.name, (*a.index[:-1], numbers[a.index[-1]]))
                            for a in atoms(f) if a.index and a.index[-1] in numbers})


def check_rule(f: Formula, scenario: Scenario, where: str) -> int:
    """A user rule the planner can use, else :class:`~dualarm_mpc.model.scenario.ScenarioError`
    naming ``where``: known atoms over the scenario's hands and objects, no goal atom under a
    negation, no more object placeholders than a step has objects (the rule would expand to nothing)
    and an expansion of at most ``MAX_RULE_INSTANCES``. Returns the size of that expansion in
    formula nodes."""
    n = scenario.n_objects
    for atom in sorted(atoms(f), key=str):
        problem = _atom_problem(atom, n, [o.name for o in scenario.task.objects])
        if problem:
            raise ScenarioError(f"{where}: {problem}")
    for atom in sorted(negated_atoms(f), key=str):
        if atom.name == "theta":
            raise ScenarioError(
                f"{where}: {atom} appears negated: a goal atom is linked to the state "
                "one-sidedly (eq. 7: θ = 1 → x ∈ H), so its negation cannot be encoded soundly; "
                "state the rule with it in positive position")
    names = placeholders(f)
    objects = sorted(names - {ARM_PLACEHOLDER})
    step = min(scenario.task.n_o, n)
    if len(objects) > step:
        raise ScenarioError(
            f"{where}: {len(objects)} distinct object placeholders ({', '.join(objects)}) but a "
            f"sequential step has at most {step} objects (n_o = {scenario.task.n_o}, {n} objects): "
            "the rule would never apply")
    size = (len(ARMS) if ARM_PLACEHOLDER in names else 1) * math.perm(step, len(objects))
    if size > MAX_RULE_INSTANCES:
        raise ScenarioError(
            f"{where}: expands to {size:,} instances ({len(objects)} object placeholders over "
            f"the {step} objects of a step), more than {MAX_RULE_INSTANCES:,}; use fewer "
            "placeholders or a smaller n_o")
    return size * formula_size(f)


_ATOMS = ("the atoms are eta[i,j] (hand i = 1 right, 2 left, grabs object j) and theta[j] "
         "(object j in its goal)")


def _atom_problem(atom: Atom, n: int, names: list[str]) -> str:
    """What is wrong with ``atom`` in a rule over ``n`` objects (``names``), or "". An object
    index that is a word, not an object's name (those are numbers by now), is neither an object
    nor a placeholder: placeholders are one letter, so a misspelt name is never read as "every
    object"."""
    arity = {"eta": 2, "theta": 1}.get(atom.name)
    if arity != len(atom.index):
        return f"unknown atom {atom}: {_ATOMS}, j = 1..{n}"
    *hand, obj = atom.index
    if hand and hand[0] not in (*ARMS, ARM_PLACEHOLDER):
        return f"{atom}: the hand is 1 (right), 2 (left) or the placeholder {ARM_PLACEHOLDER}"
    if obj == ARM_PLACEHOLDER:
        return (f"{atom}: {ARM_PLACEHOLDER} is the hand placeholder; name objects by another "
                "(j, l, ...)")
    if isinstance(obj, int) and not 1 <= obj <= n:
        return f"{atom}: no object {obj} (objects 1..{n})"
    if isinstance(obj, str) and len(obj) > 1:
        shown = ", ".join(names[:10]) + (f", ... ({n} objects)" if n > 10 else "")
        return (f"{atom}: {obj} is no object's name and no placeholder (one letter: j, l, ...); "
                f"the objects: {shown}, or their numbers 1..{n}")
    return ""


def negated_atoms(f: Formula) -> set[Atom]:
    """The atoms under a negation in ``nnf(f)``, found without writing it (each nested ``<->``
    or ``xor`` doubles it): the polarity of each occurrence, each subformula visited at most
    once per polarity."""
    out: set[Atom] = set()
    seen: set[tuple[int, bool]] = set()
    stack = [(f, False)]
    while stack:
        g, negated = stack.pop()
        if (id(g), negated) in seen:
            continue
        seen.add((id(g), negated))
        if isinstance(g, Atom):
            if negated:
                out.add(g)
        elif isinstance(g, Not):
            stack.append((g.arg, not negated))
        elif isinstance(g, Implies):
            stack += [(g.lhs, not negated), (g.rhs, negated)]
        elif isinstance(g, Equiv | Xor):  # (a & b) | (!a & !b): each argument both ways
            stack += [(x, p) for x in (g.lhs, g.rhs) for p in (False, True)]
        elif isinstance(g, And | Or):
            stack += [(x, negated) for x in g.args]
        elif isinstance(g, Until | Release | WeakUntil | StrongRelease):
            stack += [(g.lhs, negated), (g.rhs, negated)]
        elif not isinstance(g, Const):
            stack.append((g.arg, negated))
    return out


def specification(scenario: Scenario, objects: list[int], m_o: int | None = None,
                  rules: list[tuple[str, Formula]] | None = None) -> Specification:
    """The specification of one sequential step over ``objects`` (0-based scenario indices)."""
    m_o = min(scenario.task.m_o if m_o is None else m_o, len(objects))
    named = rule_formulas(scenario) if rules is None else rules
    numbers = [j + 1 for j in objects]
    return Specification(
        objects=tuple(objects),
        m_o=m_o,
        delivery=scenario.task.delivery,
        task_form=scenario.task.task_form,
        rules=tuple((name, expand(f, numbers)) for name, f in named),
    )


def with_no_throw(spec: Specification) -> Specification | None:
    """``spec`` and no-throw (18) for every object of the step: a restriction (each of its plans
    is one of ``spec``'s), whose search is far quicker where ``spec`` allows relays (route
    bounds and order splits apply to every object); its plan is the step's witness
    (``sequential.plan_step``). None when no-throw is already in force for them all."""
    if spec.no_throw_for_all():
        return None
    name = "no-throw (18)"
    rule = expand(parse(RULE_TEXT[name]), [j + 1 for j in spec.objects])
    return replace(spec, rules=(*spec.rules, (f"{name}, the witness's", rule)))


# --- relaxations for the skeleton search (search.py) and the consistency check ---------------


def objects_of(formula: Formula) -> frozenset[int]:
    """The object numbers (1-based) that the atoms of ``formula`` mention."""
    return frozenset(a.index[-1] for a in atoms(formula)
                     if a.index and isinstance(a.index[-1], int))


def confined(spec: Specification) -> Specification:
    """``spec`` with only the rule instances whose atoms all name its own objects: a relaxation
    of every program over these objects or more, with the same rules, state and horizon and a
    φ_task that implies this one's. The encoder reads an atom of an object outside its program as
    a constant (η false, θ its value now), which a program holding that object does not: such an
    instance is dropped, never folded."""
    own = {j + 1 for j in spec.objects}
    return replace(spec, rules=tuple((name, conj(i for i in instances(f) if objects_of(i) <= own))
                                     for name, f in spec.rules))


def untouchable(spec: Specification, state: State, targets: Iterable[int]) -> frozenset[int]:
    """The step's objects outside ``targets`` (scenario indices) that an optimal plan may leave
    untouched: none is held now, and every rule instance that mentions one is TRUE once their η
    are FALSE at every step. Untouching them keeps the hands' motion, hence the cost, and every
    other object's motion, hence φ_task."""
    targets = set(targets)
    outside = [j for j in spec.objects if j not in targets]
    candidates = {j for j in outside if not state.grasp[:, j].any()}
    known = {Atom("eta", (i, j + 1)): False for i in (1, 2) for j in candidates}
    numbers = {j + 1 for j in candidates}
    for _, rule in spec.rules:
        for inst in instances(rule):
            if objects_of(inst) & numbers and partial(inst, known) != TRUE:
                return frozenset()  # conservative: leave every outside object free
    return frozenset(candidates)


def restricted(spec: Specification, targets: Iterable[int], keep: Iterable[int]) -> Specification:
    """A relaxation for the bounds: deliver every object of ``targets`` (φ_task stronger, as in
    the node), and keep only the rule instances whose step objects all lie in ``keep``."""
    targets = tuple(sorted(targets))
    step = {j + 1 for j in spec.objects}
    allowed = {j + 1 for j in keep}
    rules = tuple(
        (name, conj(i for i in instances(f) if (objects_of(i) & step) <= allowed))
        for name, f in spec.rules
    )
    return replace(spec, targets=targets, m_o=len(targets), task_form="counting", rules=rules)
