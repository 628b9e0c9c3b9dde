"""The solves of light events on one hierarchy and link set: the operator (rebuilt when the
hierarchy changes), base and response solves, and the push of first-bounce terms."""

import numpy as np

from ..solver import Operator, solve, tree_pull


class Solves:
    """tol: the base solution's and warm mode's tolerance; response_tol, response_float32,
    response_steps: the shapes' and lights' responses (DynamicRadiosity's docstring); threads: the
    operator's (core.parallel: the system's ray backend's count)."""

    def __init__(self, h, links, tol, response_tol, response_float32, threads=1, response_steps=None):
        self.h, self.links, self.threads = h, links, threads
        self.tol, self.response_tol, self.response_float32 = tol, response_tol, response_float32
        self.response_steps = response_steps
        self.n_hr = h.n  # the HR build's nodes (events add theirs after them)
        self._op = None
        self._op_version = None

    def operator(self):
        h = self.h
        if self._op is None or self._op_version != h.version or self._op.n != h.n:
            self._op = Operator(h, self.links, self.threads)
            self._op_version = h.version
        return self._op

    def release_work(self):
        """The operator's work arrays let go (Operator.release_work; a bake between its stages)."""
        if self._op is not None:
            self._op.release_work()

    def push(self, D):
        """D (3, n) with every node's value added to its descendants (first-bounce terms are
        stored per receiver node, not pushed)."""
        h = self.h
        D = D.copy()
        par = h.parent[: h.n]
        for lv in h.levels()[1:]:
            D[:, lv] += D[:, par[lv]]
        return D

    def _tree(self, owned):
        """((n,) True at the HR build's splits and `owned`, the HR build's node count)."""
        h, m = self.h, self.n_hr
        inner = np.zeros(h.n, bool)
        c0 = h.child0[:m]
        inner[:m] = (c0 >= 0) & (c0 < m)
        inner[np.asarray(owned, np.int64)] = True
        return inner, m

    def tree_pull(self, owned):
        """The solver's pull over the tree a response with `owned` is solved on (solve), or over the
        hierarchy's without response_steps (node means of a response's own terms, as its solve)."""
        if not self.response_steps:
            return self.operator().pull
        return tree_pull(self.operator(), self._tree(owned)[0])[0]

    def solve(self, E, B0=None, response=False, tol=None, owned=None):
        """Solve with non-negative emission; the exact solution is non-negative, so the solver's
        tiny negative excursions (GMRES is not monotone) are clipped. response: a shape's response
        (response_tol, response_float32; its power balance is not reported). tol: instead of
        those tolerances (a preview's). With response_steps a response (without tol) is that many
        GMRES steps from zero, B0 ignored: the same whatever the shape's history. owned: the
        splits below the HR leaves the shape needs (rec.owned, a light's none): such a response is
        solved on the HR build's splits and those only, other shapes' splits reading as the leaf
        they split (solver.solve's `inner`), so that it is the same bit for bit whatever other
        shapes were present when it was solved (a Live session's history against a bake of its
        final state: equal in exact arithmetic, not in rounding)."""
        op = self.operator()
        if response and self.response_float32:
            op = op.float32()
        steps = self.response_steps if response and tol is None else None
        inner = self._tree(owned) if steps and owned is not None else None
        B, rep = solve(
            self.h,
            self.links,
            E,
            B0=B0,
            tol=tol if tol is not None else self.response_tol if response else self.tol,
            op=op,
            energy=not response,
            verify=not response,  # a response's own check would be one gather in ten (Live, Cornell)
            steps=steps,
            inner=inner,
        )
        return np.maximum(B, 0.0), rep
