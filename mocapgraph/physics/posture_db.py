"""Shum & Ho's posture database (section 5): normalised postures, PCA space, nearest match, filling.

A posture is a character's joint positions ``P_d`` [J, 3] with its local rotations ``Θ_d`` [J, 4]
(wxyz), normalised: the root moved to the origin and the heading (yaw about world Z, from the hip
line, else the shoulder line) turned to zero. Near-duplicates (sum of squared position differences
below ``min_ssd`` m^2 from a kept posture) are dropped. PCA (SVD of the centred 3J-vectors) keeps
``k`` components. A query is normalised the same way, its missing joints take the database mean
(section 5.2), it is projected and its nearest posture found in the reduced space by brute force or
a k-d tree (``scipy.spatial.cKDTree``), whichever :meth:`PostureDB.choose_search` measured faster.
:meth:`PostureDB.complete_into` substitutes the missing positions and rotations from the match (P_e,
Θ_e), the match put back at the query's root and heading, as kernels (:mod:`.posture_kernels`);
their numpy reference is :func:`.reference.complete`.

Stored as ``.npz`` (arrays plus a JSON header); units metres, world Z up.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ..kinematics.quaternion import quat_multiply
from ..messages.bounded_json import loads_bounded
from . import posture_kernels as pk

FORMAT = "mocapgraph.posture_db/1"


class PostureDBError(ValueError):
    """A posture database that cannot be built or read (message names the file or the fault)."""


def _yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """wxyz rotations about +Z by ``yaw`` [N] rad."""
    return np.stack([np.cos(yaw / 2), np.zeros_like(yaw), np.zeros_like(yaw), np.sin(yaw / 2)], axis=-1)


@dataclass(frozen=True)
class Frame:
    """Which joints define the normalisation: root, and (left, right) pairs for the heading."""

    root: int
    pairs: tuple[tuple[int, int], ...]

    @staticmethod
    def of(joint_names: tuple[str, ...], parents: np.ndarray) -> "Frame":
        names = [n.lower() for n in joint_names]
        root = int(np.flatnonzero(np.asarray(parents) < 0)[0])
        pairs = []
        for stem in ("hip", "shoulder", "upleg", "arm"):
            left = [i for i, n in enumerate(names) if stem in n and "left" in n or n in (f"{stem}_l", f"l{stem}")]
            right = [i for i, n in enumerate(names) if stem in n and "right" in n or n in (f"{stem}_r", f"r{stem}")]
            if left and right:
                pairs.append((left[0], right[0]))
        if not pairs:
            raise PostureDBError("no left/right hip or shoulder joints to take the heading from")
        return Frame(root, tuple(pairs))

    def yaw_and_origin(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per posture [N, J, 3]: heading yaw [N] rad, origin [N, 3] m, and whether both were found.

        The heading comes from the first pair whose joints are both there; the origin is the root,
        else the midpoint of the first complete pair (all pairs at once: this runs every frame)."""
        L = np.array([l for l, _ in self.pairs])
        R = np.array([r for _, r in self.pairs])
        pl, pr = pos[:, L], pos[:, R]                    # [N, P, 3]
        left = pl - pr
        y = np.arctan2(-left[..., 0], left[..., 1])      # [N, P]; left along +Y means heading along +X
        mid = 0.5 * (pl + pr)
        good = np.isfinite(mid).all(2)                   # a pair is usable iff both joints are there
        first = np.argmax(good, axis=1)
        rows = np.arange(len(pos))
        found = good[rows, first]
        yaw = np.where(found, y[rows, first], np.nan)
        origin = pos[:, self.root].copy()
        bad = ~np.isfinite(origin).all(1) & found
        origin[bad] = mid[rows, first][bad]
        ok = np.isfinite(yaw) & np.isfinite(origin).all(1)
        return yaw, origin, ok


def rz_rows(yaw: float) -> np.ndarray:
    """Row vectors times this turn about +Z by ``yaw`` rad."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def normalise_one(frame: Frame, pos: np.ndarray) -> tuple[np.ndarray | None, float, np.ndarray]:
    """:func:`normalise` of one posture [J, 3] (the per-frame query): (normalised [J, 3] or None
    when it has no heading or origin, yaw rad, origin [3] m). The heading pairs are a handful of
    joints, read as scalars."""
    for l, r in frame.pairs:  # the first pair whose both joints are there (<= 4 pairs, not joints)
        a, b = pos[l].tolist(), pos[r].tolist()
        if all(map(math.isfinite, a + b)):
            break
    else:
        return None, 0.0, np.zeros(3)
    yaw = math.atan2(-(a[0] - b[0]), a[1] - b[1])   # left along +Y means heading along +X
    origin = pos[frame.root]
    if not np.isfinite(origin).all():
        origin = 0.5 * (np.asarray(a) + np.asarray(b))
    return (pos - origin) @ rz_rows(-yaw), yaw, origin


def normalise(frame: Frame, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Postures [N, J, 3] with root at the origin and heading zero; returns (normalised, yaw, origin, ok)."""
    yaw, origin, ok = frame.yaw_and_origin(pos)
    y0 = np.where(np.isfinite(yaw), yaw, 0.0)
    c, s = np.cos(-y0), np.sin(-y0)
    d = pos - origin[:, None]
    out = np.empty_like(d)
    out[..., 0] = c[:, None] * d[..., 0] - s[:, None] * d[..., 1]
    out[..., 1] = s[:, None] * d[..., 0] + c[:, None] * d[..., 1]
    out[..., 2] = d[..., 2]
    return out, yaw, origin, ok


@dataclass
class PostureDB:
    """The database: postures, their PCA space and the chosen search."""

    joint_names: tuple[str, ...]
    parents: np.ndarray
    positions: np.ndarray        # [N, J, 3] m, normalised
    rotations: np.ndarray        # [N, J, 4] wxyz local; the root's with the heading removed
    mean: np.ndarray             # [3J]
    components: np.ndarray       # [K, 3J] all principal axes (rows), by decreasing variance
    k: int = 7
    sources: tuple[str, ...] = ()
    search: str = "brute"        # "brute" or "kdtree" (numpy path)
    search_compiled: str = "brute"   # the same choice for the compiled path (complete_into)
    rerank: int = 8              # the nearest this many in the reduced space, re-ranked in the full one
    _tree: cKDTree | None = field(default=None, repr=False)
    _reduced: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.frame = Frame.of(self.joint_names, self.parents)
        self.set_k(self.k)

    # ----- construction ------------------------------------------------------------------------
    @classmethod
    def build(cls, joint_names, parents, positions: np.ndarray, rotations: np.ndarray, *, k: int = 7,
              min_ssd: float = 0.01, sources: tuple[str, ...] = ()) -> "PostureDB":
        """From world postures [N, J, 3] and local rotations [N, J, 4] of one character."""
        joint_names = tuple(joint_names)
        parents = np.asarray(parents, dtype=np.int64)
        pos = np.asarray(positions, float)
        rot = np.asarray(rotations, float)
        if pos.ndim != 3 or pos.shape[1:] != (len(joint_names), 3) or rot.shape[:2] != pos.shape[:2]:
            raise PostureDBError(f"postures {pos.shape} / rotations {rot.shape} do not match {len(joint_names)} joints")
        frame = Frame.of(joint_names, parents)
        norm, yaw, _, ok = normalise(frame, pos)
        ok &= np.isfinite(norm).all((1, 2)) & np.isfinite(rot).all((1, 2))
        norm, rot, yaw = norm[ok], rot[ok].copy(), yaw[ok]
        if len(norm) < 2:
            raise PostureDBError(f"only {len(norm)} complete postures: a database needs at least 2")
        root = frame.root
        rot[:, root] = quat_multiply(_yaw_quat(-yaw), rot[:, root])
        keep = dedupe(norm.reshape(len(norm), -1), min_ssd)
        norm, rot = norm[keep], rot[keep]
        flat = norm.reshape(len(norm), -1)
        mean = flat.mean(0)
        _, _, vt = np.linalg.svd(flat - mean, full_matrices=False)
        return cls(joint_names, parents, norm, rot, mean, vt, k=min(k, vt.shape[0]), sources=tuple(sources))

    def set_k(self, k: int) -> None:
        """Use the first ``k`` principal components (1 .. all)."""
        if not 1 <= k <= self.components.shape[0]:
            raise PostureDBError(f"k = {k}: the database has {self.components.shape[0]} components")
        self.k = int(k)
        self._basis = self.components[:k]
        self._reduced = (self.positions.reshape(len(self.positions), -1) - self.mean) @ self._basis.T
        self._sqnorm = (self._reduced * self._reduced).sum(1)
        # the brute-force search as one matmul: [q, 1] @ [-2 R^T; |r|^2] = |r|^2 - 2 q.r, the
        # squared distance less the query's own |q|^2 (the same for every posture)
        self._search_t = np.ascontiguousarray(np.vstack([-2.0 * self._reduced.T, self._sqnorm[None]]))
        self._query = np.ones(self.k + 1)
        self._tree = cKDTree(self._reduced)
        # the compiled path's contiguous arrays and buffers, as its kernels read them
        self._k = tuple(pk.DBArrays(np.array([l for l, _ in self.frame.pairs], dtype=np.int64),
                                    np.array([r for _, r in self.frame.pairs], dtype=np.int64), int(self.frame.root),
                                    np.ascontiguousarray(self.mean, dtype=np.float64),
                                    np.ascontiguousarray(self._basis, dtype=np.float64),
                                    np.ascontiguousarray(self._reduced.T), np.ascontiguousarray(self._sqnorm),
                                    np.zeros(len(self._reduced)),
                                    np.ascontiguousarray(self.positions, dtype=np.float64),
                                    np.ascontiguousarray(self.rotations, dtype=np.float64), np.zeros(self.k),
                                    np.zeros(4), np.zeros(max(1, min(int(self.rerank), len(self._reduced))),
                                                          dtype=np.int64)))

    @property
    def kernel_arrays(self) -> tuple:
        """The database as :mod:`.posture_kernels` reads it (a plain tuple laid out as ``DBArrays``)."""
        return self._k

    def __len__(self) -> int:
        return len(self.positions)

    # ----- queries -----------------------------------------------------------------------------
    def project(self, norm_flat: np.ndarray) -> np.ndarray:
        """Normalised 3J-vectors [N, 3J] (NaN: missing, takes the mean) -> reduced [N, k]."""
        x = np.where(np.isfinite(norm_flat), norm_flat, self.mean)
        return (x - self.mean) @ self._basis.T

    def nearest(self, reduced: np.ndarray, how: str | None = None) -> np.ndarray:
        """Index [N] of the nearest posture to each reduced query [N, k] (sum of squared differences)."""
        how = how or self.search
        if how == "kdtree":
            return self._tree.query(reduced, k=1)[1]
        if len(reduced) == 1:  # the live case: one vector-matrix product over a (k+1) x N matrix
            # (contiguous along the postures), then the argmin
            q = self._query
            q[:-1] = reduced[0]
            return np.array([np.argmin(q @ self._search_t)])
        d = self._sqnorm[None] - 2.0 * reduced @ self._reduced.T
        return np.argmin(d, axis=1)

    def choose_search(self, trials: int = 200) -> dict[str, float]:
        """Time one-query searches both ways (ms per query) and keep the faster."""
        rng = np.random.default_rng(0)
        q = self._reduced[rng.integers(0, len(self), trials)] + rng.normal(0, 0.01, (trials, self.k))
        out = {}
        for how in ("brute", "kdtree"):
            self.nearest(q[:1], how)
            t = time.perf_counter()
            for i in range(trials):
                self.nearest(q[i:i + 1], how)
            out[how] = (time.perf_counter() - t) / trials * 1e3
        self.search = min(out, key=out.get)
        return out

    def choose_search_compiled(self, trials: int = 200) -> dict[str, float]:
        """Time one-query searches of the compiled path (the brute-force kernel against the k-d
        tree, each called as :meth:`complete_into` calls it; ms per query) and keep the faster."""
        rng = np.random.default_rng(0)
        q = self._reduced[rng.integers(0, len(self), trials)] + rng.normal(0, 0.01, (trials, self.k))
        k = pk.DBArrays(*self._k)
        red, sq, dist = k.reduced_t, k.sqnorm, k.dist
        out = {}
        pk.nearest(q[0], red, sq, dist)
        t = time.perf_counter()
        for i in range(trials):
            pk.nearest(q[i], red, sq, dist)
        out["brute"] = (time.perf_counter() - t) / trials * 1e3
        tree = self._tree
        tree.query(q[0], k=1)
        t = time.perf_counter()
        for i in range(trials):
            tree.query(q[i], k=1)
        out["kdtree"] = (time.perf_counter() - t) / trials * 1e3
        self.search_compiled = min(out, key=out.get)
        return out

    def complete_into(self, pos: np.ndarray, rot: np.ndarray, filled: np.ndarray) -> int:
        """:meth:`complete` as kernels, in place: missing rows of ``pos`` [J, 3] and ``rot`` [J, 4]
        (C-contiguous float64) from the nearest posture; ``filled`` [J] bool marks them. Returns the
        match index, or -1 when the query has no root/heading (nothing filled)."""
        if self.search_compiled == "brute":
            return pk.complete_brute(pos, rot, self._k, filled)
        if not pk.query(pos, self._k):
            filled[:] = False
            return -1
        cands = self._k[12]
        got = self._tree.query(self._k[10], k=cands.shape[0])[1]   # q, the query's reduced coordinates
        cands[:] = np.atleast_1d(got)
        idx = int(pk.best_full(pos, self._k, cands.shape[0]))
        pk.fill(idx, self._k, pos, rot, filled)
        return idx

    # ----- files -------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        header = dict(format=FORMAT, joint_names=list(self.joint_names), k=self.k, sources=list(self.sources),
                      search=self.search)
        np.savez_compressed(path, header=np.array(json.dumps(header)), parents=self.parents,
                            positions=self.positions, rotations=self.rotations, mean=self.mean,
                            components=self.components)

    @classmethod
    def load(cls, path: str | Path) -> "PostureDB":
        if Path(path).exists() and not Path(path).is_file():  # a device or fifo: np.load would read forever or block
            raise PostureDBError(f"{path}: not a regular file")
        try:
            with np.load(path, allow_pickle=False) as z:
                header = loads_bounded(str(z["header"]), max_depth=8)   # (a hostile file's header: bounded)
                if header.get("format") != FORMAT:
                    raise PostureDBError(f"{path}: not a posture database ({header.get('format')!r})")
                return cls(tuple(header["joint_names"]), z["parents"], z["positions"], z["rotations"], z["mean"],
                           z["components"], k=int(header["k"]), sources=tuple(header.get("sources", ())),
                           search=header.get("search", "brute"))
        except PostureDBError:
            raise
        except (OSError, KeyError, ValueError, json.JSONDecodeError) as exc:
            raise PostureDBError(f"{path}: cannot read posture database ({exc})") from None


def open_posture_db(spec: str) -> PostureDB | None:
    """The database a tracker names: '' none; ``synthetic:CLIPS`` built now on standard_20 (see
    :func:`~mocapgraph.physics.synthetic_targets.synthetic_postures`); else an ``.npz`` file. Its
    nearest-posture search is measured here and the faster way chosen (brute-force kernel or k-d
    tree). PostureDBError or ValueError naming the fault."""
    if not spec:
        return None
    if spec.startswith("synthetic:"):
        from ..retarget.character import standard_20
        from .synthetic_targets import synthetic_postures
        pos, rot = synthetic_postures(spec)
        ch = standard_20()
        db = PostureDB.build(ch.joint_names, ch.parents, pos, rot, sources=(spec,))
        db.choose_search()
    else:
        db = PostureDB.load(spec)
    db.choose_search_compiled()
    return db


def dedupe(flat: np.ndarray, min_ssd: float) -> np.ndarray:
    """Indices of postures [N, D] kept when each must differ from every kept one by at least
    ``min_ssd`` (sum of squared differences); greedy in order, a k-d tree finds the neighbours."""
    if min_ssd <= 0:
        return np.arange(len(flat))
    r = np.sqrt(min_ssd)
    tree = cKDTree(flat)
    kept = np.zeros(len(flat), dtype=bool)
    covered = np.zeros(len(flat), dtype=bool)
    for i in range(len(flat)):  # a build-time pass, not a per-frame path
        if covered[i]:
            continue
        kept[i] = True
        covered[tree.query_ball_point(flat[i], r)] = True
    return np.flatnonzero(kept)
