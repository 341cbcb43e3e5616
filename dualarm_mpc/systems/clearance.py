"""Clearance: the smallest distance between given pairs of geometries over a run, measured by
SceneGraph: between the two arms, and between the hands and the objects."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import GeometryId, QueryObject
from pydrake.systems.framework import LeafSystem

# 50 samples a second, more than the replay's 32 frames: at the hands' top speed (0.5 m/s) they
# move 1 cm between samples. Each sample costs about 0.1 ms (48 pairs).
CLEARANCE_PERIOD_S = 0.02


class Clearance(LeafSystem):
    """Samples the signed distance of ``pairs`` every ``period`` and keeps the least.

    .. pydrake_system::

        name: Clearance
        input_ports:
        - geometry_query
        output_ports:
        - min_clearance

    ``geometry_query``: SceneGraph's query output. ``pairs``: the pairs of collision geometries
    whose signed distance is measured (``Station.arm_pairs``, ``Station.hand_object_pairs``;
    SceneGraph measures a pair whether or not its contact is filtered out).
    ``min_clearance`` (1): the least signed distance (m) of any pair
    at any sample so far, negative for a penetration; +inf before the first sample (t = 0).
    """

    def __init__(self, pairs: Sequence[tuple[GeometryId, GeometryId]],
                 period: float = CLEARANCE_PERIOD_S):
        super().__init__()
        if not pairs:
            raise ValueError("pairs: expected at least one pair of geometries")
        if period <= 0:
            raise ValueError(f"period must be positive, got {period}")
        self._pairs = tuple(pairs)
        self._query = self.DeclareAbstractInputPort(
            "geometry_query", AbstractValue.Make(QueryObject()))
        self._state = self.DeclareDiscreteState(np.array([np.inf]))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._sample)
        self._min_clearance = self.DeclareStateOutputPort("min_clearance", self._state)

    def get_geometry_query_input_port(self):
        return self._query

    def get_min_clearance_output_port(self):
        return self._min_clearance

    def clearance(self, query: QueryObject) -> float:
        """The least signed distance of the pairs now."""
        return min(query.ComputeSignedDistancePairClosestPoints(a, b).distance
                   for a, b in self._pairs)

    def _sample(self, context, discrete_state):
        least = min(context.get_discrete_state(self._state).GetAtIndex(0),
                    self.clearance(self._query.Eval(context)))
        discrete_state.get_mutable_vector(self._state).SetAtIndex(0, least)
