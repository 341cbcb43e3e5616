"""The task and its model: scenario, MLD system (§IV-A), specifications (13), (18)-(21), plans and
their verification."""
