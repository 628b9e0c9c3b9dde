"""Blender lights on a DynamicRadiosity (issue 20): each light's first bounce as emission on the
nodes it lights (the seed's "irregular light source"), its response solved once per geometry, a
colour or strength change a scale.

FE-style for now: the light's unit direct light is averaged over every HR leaf's 2 x 2 Gauss
points (core.lights.node_incident, shadow rays per point), times the leaf's reflectance, and that
field's response U (3, n) is solved like a light shape's: B = B_base + sum_s E_s U_s +
sum_l scale_l U_l. AR-style refinement along a spot's edge or a shadow boundary (splitting leaves
below the HR level) is not done: the edge is as sharp as the HR leaves in the hierarchy's values;
the final gather's direct light at the output samples is exact."""

from collections import OrderedDict
import time

import numpy as np

from ..lights import node_incident
from .records import EventReport


class _LightRec:
    __slots__ = ("key", "name", "light", "geom_key", "scale", "U", "D", "method")

    def __init__(self, key, light):
        self.key, self.name, self.light = key, light.name or str(key), light
        self.geom_key = light.geom_key
        self.scale = light.scale
        self.U = None  # (3, n) response at unit scale
        self.D = None  # (3, n) first-bounce radiance at unit scale on the HR leaves (not pushed)
        self.method = "FE"


LIGHT_RAYS = 4  # shadow rays per Gauss point for lights with a size


class Lights:
    """The Blender lights on a DynamicRadiosity: recs (key -> _LightRec, the lights in effect) and
    their first bounce and responses. nodes: the events' NodeState; solves: the events' Solves;
    far: a distance beyond the scene (sun rays); incremental: "response" or "warm";
    records(): every record holding node arrays (NodeState.sync); warm_moves: a moved light's
    response starts from the old one's (DynamicRadiosity's docstring)."""

    def __init__(self, system, nodes, solves, far, incremental, records, warm_moves=True):
        self.system, self.nodes, self.solves, self.records = system, nodes, solves, records
        self.far, self.incremental, self.warm_moves = far, incremental, warm_moves
        self.recs = OrderedDict()

    def diff(self, lights):
        """Events making `lights` (key -> core.lights.Light, the full set) current."""
        evs = []
        for k in [k for k in self.recs if k not in lights]:
            rec = self.recs.pop(k)
            evs.append(EventReport("remove", k, rec.name, "LIGHT"))
        for k, L in lights.items():
            rec = self.recs.get(k)
            if rec is not None and rec.geom_key == L.geom_key:
                if not np.array_equal(rec.scale, L.scale):
                    rec.scale, rec.light = L.scale, L
                    evs.append(EventReport("emission", k, rec.name, "LIGHT"))
                continue
            t0 = time.perf_counter()
            old = rec
            rec = _LightRec(k, L)
            its = self._light_response(rec, old)
            self.recs[k] = rec
            ev = EventReport("reshape" if old is not None else "add", k, rec.name, "LIGHT")
            ev.iterations = its
            ev.seconds = time.perf_counter() - t0
            evs.append(ev)
        return evs

    def _hr_leaves(self):
        n_hr = self.nodes.n_hr
        c0 = self.system.h.child0[:n_hr]
        return np.flatnonzero((c0 < 0) | (c0 >= n_hr))

    def _light_response(self, rec, old=None):
        """rec.D: the light's first bounce per unit scale on the HR leaves; rec.U its response."""
        self.nodes.sync(self.records())
        h, pt = self.system.h, self.system.patches
        leaves = self._hr_leaves()
        eps = self.system.refiner.eps
        unit = 2.0 ** (np.floor(np.log2(np.sqrt(float(pt.area.sum())))) - 12)
        v = node_incident(h, leaves, rec.light, self.system.backend, eps, LIGHT_RAYS, unit=unit, far=self.far)
        D = np.zeros((3, h.n))
        D[:, leaves] = pt.reflectance[:, h.patch[leaves]] * v
        rec.D = D
        if self.incremental == "warm":
            return 0
        E = self.solves.push(D)
        guess = None
        if self.warm_moves and old is not None and old.U is not None:  # lights the room much as before
            guess = E + (old.U - self.solves.push(old.D))
        U, rep = self.solves.solve(E, B0=guess, response=True, owned=())  # (Solves.solve)
        rec.U = U
        return rep.iterations
