"""Clearance: the smallest distance between given pairs of geometries over a run, measured by
SceneGraph: between the two arms, and between the hands and the objects."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    Box,
    Capsule,
    Convex,
    Cylinder,
    Ellipsoid,
    GeometryId,
    Mesh,
    QueryObject,
    Shape,
    Sphere,
)
from pydrake.systems.framework import LeafSystem

# 50 samples a second, more than the replay's 32 frames: at the hands' top speed (0.5 m/s) they
# move 1 cm between samples. Each sample costs about 0.1 ms (48 pairs).
CLEARANCE_PERIOD_S = 0.02


def bounding_radius(shape: Shape) -> float:
    """The radius of a ball about the geometry's frame origin that holds ``shape`` (inf where no
    such ball is known, as for a half-space)."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Box):
        return 0.5 * float(np.linalg.norm(shape.size()))
    if isinstance(shape, Cylinder):
        return math.hypot(shape.radius(), shape.length() / 2)
    if isinstance(shape, Capsule):
        return shape.radius() + shape.length() / 2
    if isinstance(shape, Ellipsoid):
        return max(shape.a(), shape.b(), shape.c())
    if isinstance(shape, (Mesh, Convex)):
        # times the scale where it enlarges: a ball about the hull holds the mesh, whether or
        # not the hull Drake reports is scaled already
        hull = shape.GetConvexHull()
        far = max(float(np.linalg.norm(hull.vertex(v))) for v in range(hull.num_vertices()))
        return far * max(1.0, float(np.abs(shape.scale3()).max()))
    return math.inf


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
        self._ids = list(dict.fromkeys(g for pair in self._pairs for g in pair))
        index = {g: n for n, g in enumerate(self._ids)}
        self._ends = np.array([[index[a], index[b]] for a, b in self._pairs]).T
        self._radius: np.ndarray | None = None  # of each geometry, read on the first sample
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
        """The least signed distance of the pairs now. A pair is no closer than its geometries'
        origins less their bounding radii, so the pairs are measured nearest such bound first,
        and those whose bound is no less than the least distance found are not measured: the
        same least, from a few pairs of a robot's hundreds."""
        if self._radius is None:
            inspector = query.inspector()
            self._radius = np.array([bounding_radius(inspector.GetShape(g)) for g in self._ids])
        origin = np.array([query.GetPoseInWorld(g).translation() for g in self._ids])
        a, b = self._ends
        bound = np.linalg.norm(origin[a] - origin[b], axis=1) - self._radius[a] - self._radius[b]
        least = math.inf
        for n in np.argsort(bound, kind="stable"):
            if bound[n] >= least:
                break
            least = min(least, query.ComputeSignedDistancePairClosestPoints(
                *self._pairs[n]).distance)
        return least

    def _sample(self, context, discrete_state):
        least = min(context.get_discrete_state(self._state).GetAtIndex(0),
                    self.clearance(self._query.Eval(context)))
        discrete_state.get_mutable_vector(self._state).SetAtIndex(0, least)
