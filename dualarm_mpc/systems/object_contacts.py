"""ObjectContacts: which pairs of objects touched while one of them moved, from the plant's contact
results: a carried or thrown box that shoves another, or a pushed one that shoves a third.

Two boxes touching at rest (side by side in a goal) do not count: only a contact with either box
moving faster than ``mld.REST_SPEED`` does. Sampled as the clearances are (systems/clearance.py),
every 20 ms; the summary's ``object_contacts``."""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialVelocity
from pydrake.multibody.plant import ContactResults, MultibodyPlant
from pydrake.multibody.tree import RigidBody
from pydrake.systems.framework import LeafSystem

from dualarm_mpc.model.mld import REST_SPEED
from dualarm_mpc.systems.clearance import CLEARANCE_PERIOD_S


class ObjectContacts(LeafSystem):
    """Samples the plant's contact results every ``period`` and keeps, per pair of objects, when
    they first touched while one of them moved and in how many samples they did.

    .. pydrake_system::

        name: ObjectContacts
        input_ports:
        - contact_results
        - body_spatial_velocities
        output_ports:
        - first_contact
        - contact_samples

    ``contact_results`` and ``body_spatial_velocities``: the plant's outputs of those names.
    Pairs (a, b), a < b, in the order of :meth:`pairs`. ``first_contact`` (one per pair): the
    time of the first sample at which the pair touched with either moving, +inf if never;
    ``contact_samples``: how many samples found it so (times ``period``: how long, about).
    A contact is any point pair or hydroelastic surface between two bodies of the objects (a
    box, or a support sphere of one under the other's box)."""

    def __init__(self, plant: MultibodyPlant, objects: Sequence[RigidBody],
                 period: float = CLEARANCE_PERIOD_S):
        super().__init__()
        if period <= 0:
            raise ValueError(f"period must be positive, got {period}")
        self._body_object = {b.index(): j for j, b in enumerate(objects)}
        self._bodies = [int(b.index()) for b in objects]
        self._geometry_object = {
            g: self._body_object[b.index()] for b in objects
            for g in plant.GetCollisionGeometriesForBody(b)}
        n = len(objects)
        self._pairs = list(itertools.combinations(range(n), 2))
        self._pair_index = {p: k for k, p in enumerate(self._pairs)}
        self._results = self.DeclareAbstractInputPort(
            "contact_results", AbstractValue.Make(ContactResults()))
        self._velocities = self.DeclareAbstractInputPort(
            "body_spatial_velocities", AbstractValue.Make([SpatialVelocity()]))
        self._first = self.DeclareDiscreteState(np.full(len(self._pairs), np.inf))
        self._samples = self.DeclareDiscreteState(np.zeros(len(self._pairs)))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._sample)
        self._first_contact = self.DeclareStateOutputPort("first_contact", self._first)
        self._contact_samples = self.DeclareStateOutputPort("contact_samples", self._samples)

    def pairs(self) -> list[tuple[int, int]]:
        """The pairs of objects (a, b), a < b, as the outputs order them."""
        return list(self._pairs)

    def get_contact_results_input_port(self):
        return self._results

    def get_body_spatial_velocities_input_port(self):
        return self._velocities

    def get_first_contact_output_port(self):
        return self._first_contact

    def get_contact_samples_output_port(self):
        return self._contact_samples

    def touching(self, results: ContactResults) -> set[tuple[int, int]]:
        """The pairs of objects in contact in ``results``."""
        found = set()
        for k in range(results.num_point_pair_contacts()):
            info = results.point_pair_contact_info(k)
            found.add((self._body_object.get(info.bodyA_index()),
                       self._body_object.get(info.bodyB_index())))
        for k in range(results.num_hydroelastic_contacts()):
            surface = results.hydroelastic_contact_info(k).contact_surface()
            found.add((self._geometry_object.get(surface.id_M()),
                       self._geometry_object.get(surface.id_N())))
        return {(min(a, b), max(a, b)) for a, b in found
                if a is not None and b is not None and a != b}

    def _sample(self, context, discrete_state):
        touching = self.touching(self._results.Eval(context))
        if not touching:
            return
        velocities = self._velocities.Eval(context)
        moving = [np.linalg.norm(velocities[b].translational()) > REST_SPEED
                  for b in self._bodies]
        first = discrete_state.get_mutable_vector(self._first)
        samples = discrete_state.get_mutable_vector(self._samples)
        for a, b in touching:
            if moving[a] or moving[b]:
                k = self._pair_index[(a, b)]
                first.SetAtIndex(k, min(first.GetAtIndex(k), context.get_time()))
                samples.SetAtIndex(k, samples.GetAtIndex(k) + 1)
