"""Links: symmetric link pairs between hierarchy nodes and the directed, receiver-sorted (CSR)
arrays the solver gathers over, with far links (farlinks.py) and push corrections attached."""

import numpy as np

from . import cluster
from .parallel import batch_map


class Links:
    """Symmetric link pairs plus the directed, receiver-sorted (CSR) arrays the solver gathers over."""

    def __init__(self, a, b, f_ab, f_ba, vis, corr=None, far=None):
        self.a, self.b = np.asarray(a, np.int32), np.asarray(b, np.int32)
        self.far = far  # farlinks.FarLinks: links with a cluster end (None without clustering)
        self.f_ab, self.f_ba, self.vis = (
            np.asarray(f_ab, float),
            np.asarray(f_ba, float),
            np.asarray(vis, float),
        )
        # Push corrections (see push_corrections): directed (leaf, source, dF) terms whose dF sum to
        # zero, area-weighted, over each corrected link's receiver. Dropped by select/concat.
        self.corr = corr
        self._csr = self._ext = None

    def __len__(self):
        """All links: between patch nodes and with a cluster end."""
        return len(self.a) + self.n_far

    @property
    def n_far(self):
        return 0 if self.far is None else len(self.far)

    @staticmethod
    def empty():
        z = np.zeros(0)
        return Links(z.astype(np.int64), z.astype(np.int64), z, z, z)

    def concat(self, other):
        """Patch-node links of both; far links of self."""
        return Links(
            *(
                np.concatenate([getattr(self, k), getattr(other, k)])
                for k in ("a", "b", "f_ab", "f_ba", "vis")
            ),
            far=self.far,
        )

    def select(self, mask):
        """A subset of the patch-node links (mask over them); far links kept."""
        return Links(
            self.a[mask], self.b[mask], self.f_ab[mask], self.f_ba[mask], self.vis[mask], far=self.far
        )

    def remap(self, remap):
        """After Hierarchy.compact: renumber nodes (links must not touch deleted nodes)."""
        corr = None if self.corr is None else (remap[self.corr[0]], remap[self.corr[1]], self.corr[2])
        far = None if self.far is None else self.far.remap(remap)
        return Links(remap[self.a], remap[self.b], self.f_ab, self.f_ba, self.vis, corr, far)

    def directed(self):
        """(recv, src, F) with F = form factor x visibility, sorted by receiver, zero links dropped."""
        return self._directed()[:3]

    def _directed(self):
        """directed() and a mask of its push-correction terms."""
        if self._csr is None:
            recv = np.concatenate([self.a, self.b])
            src = np.concatenate([self.b, self.a])
            f = np.concatenate([self.f_ab * self.vis, self.f_ba * self.vis])
            corr = np.zeros(len(f), bool)
            keep = f > 0
            if self.corr is not None:
                recv, src, f = (np.concatenate([x, c]) for x, c in zip((recv, src, f), self.corr))
                corr = np.concatenate([corr, np.ones(len(self.corr[0]), bool)])
                keep = np.concatenate([keep, self.corr[2] != 0])
            order = np.argsort(recv[keep], kind="stable")
            self._csr = (
                recv[keep][order].astype(np.int32),
                src[keep][order].astype(np.int32),
                f[keep][order],
                corr[keep][order],
            )
        return self._csr

    def extended(self, h, threads=1):
        """The solver's gather terms. Without far links: directed() (recv, src, f, is_correction).
        With them, the two passes of farlinks.FarLinks.terms(): (pass1, main) where pass1 =
        (t_slot, src, w) fills one intermediate value per far-link direction from the X space
        (cluster slots first, patch node i at SLOTS x C + i), and main = (recv, src, f,
        is_correction) gathers into the Y space (same layout) from Z = [intermediates | X]:
        the patch-node links and corrections plus the far links' second pass, sorted by
        receiver. Cached (node geometry never changes under a link set: events only add nodes
        below the leaves, and compact makes new Links). threads: the far links' terms by chunks
        (core.parallel; the same terms for any count)."""
        if self.far is None or not len(self.far):
            return self._directed()
        if getattr(self, "_ext", None) is None:
            recv, src, f, corr = self._directed()
            off = cluster.SLOTS * self.far.tree.C
            nT = 2 * len(self.far)
            pass1, (fr, fs, fw, fc) = self.far.terms(h, threads=threads)
            r = np.concatenate([recv.astype(np.int64) + off, fr])
            # the two sorts, then the seven reorderings, each its own array on the threads
            sort = lambda k: np.argsort(k, kind="stable")
            order, o1 = batch_map(sort, [(r,), (pass1[0],)], threads)
            cols = [
                (r, order, np.int32),
                (np.concatenate([src.astype(np.int64) + off + nT, fs]), order, np.int32),
                (np.concatenate([f, fw]), order, None),
                (np.concatenate([corr, fc]), order, None),
                *((x, o1, None) for x in pass1),
            ]
            cols = batch_map(lambda x, o, dt: x[o] if dt is None else x[o].astype(dt), cols, threads)
            self._ext = (tuple(cols[4:]), tuple(cols[:4]))
            self._csr = None  # held inside main (shifted); directed() rebuilds it if asked
        return self._ext

    @property
    def n_corrections(self):
        return 0 if self.corr is None else len(self.corr[0])

    @property
    def n_directed(self):
        return len(self.directed()[0])
