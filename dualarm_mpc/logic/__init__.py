"""LTLf: the formula tree, its text syntax and the independent evaluator (paper §III-D)."""
