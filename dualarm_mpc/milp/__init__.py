"""One horizon as a MILP: linear blocks, the MLD rows, the LTL encoding, the solver boundary and
its back-ends."""
