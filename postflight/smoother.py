"""Fixed-interval smoother over the firmware's own filter (post-flight; it does not run on the balloon).

The causal filter can only use the past, so its wind lags the truth. After the flight every sample is
known, and the best estimate at time t uses the samples after t as well. This is the modified
Bryson-Frazier (MBF) form of the Rauch-Tung-Striebel smoother, in the linearisation the filter used:

* forward, the filter runs as on the balloon; a recorder attached to it (``WindEkf.recorder``) sees
  every prediction (F) and every fusion (H, S^-1, innovation, gain K) and folds them, between two
  points of an output grid a and b, into the affine map the backward pass needs:

      lambda_a = Phi^T lambda_b + g,     Lambda_a = Phi^T Lambda_b Phi + G,

  with Phi the product of the error-transition maps of the events in between (F for a prediction,
  I - K H for a fusion) and g, G the information of the fusions in between, each carried back to a:
  g = sum Pi_e^T H_e^T S_e^-1 nu_e and G = sum Pi_e^T H_e^T S_e^-1 H_e Pi_e (Pi_e: the product of the
  maps before event e). Only the grid points are stored (x, P, Phi, g, G), not every step.
* backward, from the end of each segment (lambda = 0, Lambda = 0 at its last point):

      x_s = x + P lambda,      P_s = P - P Lambda P.

  This equals the RTS smoother at the grid points for the linearised filter, needs no inverse of a
  predicted covariance and no process noise (both are implicit in the stored P).

Wherever the control logic re-places the state instead of fusing a measurement (release, taut entry,
a reset of the height or of the taut state, a numeric reset, a reboot, the drag scale frozen), the
chain breaks: the smoother runs in segments between such events and a segment's last point keeps the
filter's own estimate. ``Segments`` in the result says where they start.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

BLOCK = 2048  # grid points per storage block


@dataclass
class Smoothed:
    """The grid: the filter's (causal) and the smoothed state and covariance at each point."""

    t_us: np.ndarray  # (n,) int64
    x: np.ndarray  # (n, N) causal state (after the step's fusions)
    P: np.ndarray  # (n, N, N) causal covariance
    xs: np.ndarray  # (n, N) smoothed state
    Ps: np.ndarray  # (n, N, N) smoothed covariance
    segment_start: np.ndarray  # (n,) bool: a new segment starts here (no link to the point before)
    # the states whose covariance P and Ps hold, in order (all of them unless the recorder was told fewer):
    # P[:, i, j] is the covariance of states cov_states[i] and cov_states[j]
    cov_states: tuple[int, ...] = ()
    # the states x and xs hold, in order (all of them unless the recorder was told fewer)
    x_states: tuple[int, ...] = ()

    def var(self, state: int, smoothed: bool = True) -> np.ndarray:
        """The (smoothed or causal) variance of one state at every grid point."""
        i = self.cov_states.index(state) if self.cov_states else state
        return (self.Ps if smoothed else self.P)[:, i, i]

    def state(self, state: int, smoothed: bool = True) -> np.ndarray:
        """The (smoothed or causal) estimate of one state at every grid point."""
        i = self.x_states.index(state) if self.x_states else state
        return (self.xs if smoothed else self.x)[:, i]


class SmootherRecorder:
    """Forward half of the MBF smoother: attach with ``ekf.recorder = SmootherRecorder(N)`` and call
    ``grid_point`` after the filter steps that make the output grid (the caller chooses them).
    Memory per grid point: 3 N^2 + 2 N floats stored (7.2 kB at N = 17), so a 1-hour flight with a 10 Hz
    grid stores 36 000 points (260 MB), 24 hours 6.2 GB. With ``store_dir`` each full block of the store
    goes to a file there (exact, float64) and comes back one block at a time in the backward pass: memory
    then holds two blocks whatever the flight. ``cov_states`` keeps the covariances of those states only
    in the result (the whole P of every point of a day is 4 GB), e.g. the wind's two; ``x_states`` keeps
    those states of x and of the smoothed x (all 19 of a day are 260 MB)."""

    def __init__(self, n_states: int, store_dir: str | None = None, cov_states: tuple[int, ...] | None = None,
                 x_states: tuple[int, ...] | None = None) -> None:  # fmt: skip
        self.n = n = n_states
        self.store_dir = store_dir
        self.cov_states = tuple(cov_states) if cov_states is not None else tuple(range(n))
        self.x_states = tuple(x_states) if x_states is not None else tuple(range(n))
        self.Pi = np.eye(n)
        self.g = np.zeros(n)
        self.G = np.zeros((n, n))
        self._tmp = np.zeros((n, n))  # scratch: the recorder runs beside the filter at every step
        self._hp = np.zeros(n)
        self._hp_row = self._hp.reshape(1, n)
        self._hp_col = self._hp.reshape(n, 1)
        self._hp3 = np.zeros((3, n))
        self._s3 = np.zeros((3, n))
        self._v3 = np.zeros(3)
        self._vn = np.zeros(n)
        self._linked = False  # the next grid point links to the one before (no break in between)
        self._blocks: list[dict[str, np.ndarray] | str] = []  # a block in memory, or the file it went to
        self._k = BLOCK  # fill index in the newest block (BLOCK: none open)
        self.count = 0

    # -------------------------------------------------------------- events (called by WindEkf)

    def predict(self, F: np.ndarray) -> None:
        np.matmul(F, self.Pi, out=self._tmp)
        self.Pi, self._tmp = self._tmp, self.Pi

    def update(self, h: np.ndarray, s_inv: float, innov: float, k: np.ndarray) -> None:
        """A scalar fusion: row h, 1/S, innovation (against the state as updated so far), gain K."""
        hp, t = self._hp, self._tmp
        np.matmul(h, self.Pi, out=hp)
        np.multiply(hp, s_inv * innov, out=self._vn)
        np.add(self.g, self._vn, out=self.g)
        np.multiply(self._hp_col, self._hp_row, out=t)
        np.multiply(t, s_inv, out=t)
        np.add(self.G, t, out=self.G)
        np.multiply(k.reshape(-1, 1), self._hp_row, out=t)
        np.subtract(self.Pi, t, out=self.Pi)

    def update3(self, H: np.ndarray, S_inv: np.ndarray, innov: np.ndarray, K: np.ndarray) -> None:
        """A vector fusion of three rows at once."""
        hp, t = self._hp3, self._tmp
        np.matmul(H, self.Pi, out=hp)
        np.matmul(S_inv, innov, out=self._v3)
        np.matmul(self._v3, hp, out=self._vn)
        np.add(self.g, self._vn, out=self.g)
        np.matmul(S_inv, hp, out=self._s3)
        np.matmul(hp.T, self._s3, out=t)
        np.add(self.G, t, out=self.G)
        np.matmul(K, hp, out=t)
        np.subtract(self.Pi, t, out=self.Pi)

    def broken(self) -> None:
        """The state was re-placed rather than fused: the chain to the last grid point is cut."""
        self._linked = False
        self._reset()

    def grid_point(self, t_us: int, x: np.ndarray, P: np.ndarray) -> None:
        """Store a grid point: the filter's state after a step's fusions, and the map from the last one."""
        b, k = self.slots()
        b["t"][k] = t_us
        b["x"][k] = x
        b["P"][k] = P
        b["Pi"][k] = self.Pi
        b["g"][k] = self.g
        b["G"][k] = self.G
        b["linked"][k] = self._linked
        self._k += 1
        self.count += 1
        self._linked = True
        self._reset()

    def slots(self) -> tuple[dict[str, np.ndarray], int]:
        """The newest block and the first free slot in it (a new block opened, the full one spilled, when
        it has none): where ``grid_point`` writes, and where the C core's recorder writes its grid points
        directly (postflight/reprocess.py ``_CRun``; then ``filled``)."""
        if self._k == BLOCK:
            n = self.n
            self._spill()
            self._blocks.append({
                "t": np.zeros(BLOCK, np.int64), "x": np.zeros((BLOCK, n)), "P": np.zeros((BLOCK, n, n)),
                "Pi": np.zeros((BLOCK, n, n)), "g": np.zeros((BLOCK, n)), "G": np.zeros((BLOCK, n, n)),
                "linked": np.zeros(BLOCK, bool),
            })  # fmt: skip
            self._k = 0
        return self._blocks[-1], self._k  # type: ignore[return-value]

    def filled(self, m: int) -> None:
        """``m`` grid points were written from the first free slot on (by the C core's recorder, which
        keeps its own Pi, g, G and link between the points)."""
        self._k += m
        self.count += m

    def _spill(self) -> None:
        """The newest block is full: to a file in ``store_dir`` (if given), out of memory."""
        if self.store_dir is None or not self._blocks or isinstance(self._blocks[-1], str):
            return
        path = os.path.join(self.store_dir, f"smoother-block-{id(self):x}-{len(self._blocks)}.npz")
        np.savez(path, **self._blocks[-1])
        self._blocks[-1] = path

    def _block(self, bi: int) -> dict[str, np.ndarray]:
        b = self._blocks[bi]
        if isinstance(b, str):
            with np.load(b) as z:
                out = {k: z[k] for k in z.files}
            os.remove(b)
            return out
        return b

    def _reset(self) -> None:
        self.Pi[...] = 0.0
        np.fill_diagonal(self.Pi, 1.0)
        self.g.fill(0.0)
        self.G.fill(0.0)

    # -------------------------------------------------------------- backward pass

    def smooth(self, progress=None) -> Smoothed:
        """The backward pass over every segment, block by block from the end (each block's maps are
        freed once used, a spilled block read back and its file removed). ``progress(done, total)`` is
        called once per block."""
        n, m = self.n, self.count
        keep = np.asarray(self.cov_states)
        xkeep = np.asarray(self.x_states)
        blocks = self._blocks
        last = self._k
        lam = np.zeros(n)
        Lam = np.zeros((n, n))
        done = 0
        out: list[dict[str, np.ndarray]] = []
        for bi in range(len(blocks) - 1, -1, -1):
            b = self._block(bi)
            blocks[bi] = None  # type: ignore[call-overload]
            size = last if bi == len(blocks) - 1 else BLOCK
            x, P, Pi, g, G, linked = b["x"], b["P"], b["Pi"], b["g"], b["G"], b["linked"]
            xs = np.empty((size, n))
            Ps = np.empty((size, len(keep), len(keep)))
            for j in range(size - 1, -1, -1):
                Pj = P[j]
                xs[j] = x[j] + Pj @ lam
                ps = Pj - Pj @ Lam @ Pj
                Ps[j] = 0.5 * (ps + ps.T)[np.ix_(keep, keep)]
                if linked[j]:
                    pt = Pi[j].T
                    lam = pt @ lam + g[j]
                    Lam = pt @ Lam @ Pi[j] + G[j]
                else:
                    lam = np.zeros(n)
                    Lam = np.zeros((n, n))
            out.append({"t": b["t"][:size], "x": x[:size][:, xkeep], "P": P[:size][:, keep][:, :, keep],
                        "xs": xs[:, xkeep], "Ps": Ps, "linked": b["linked"][:size]})  # fmt: skip
            del b, x, P, Pi, g, G
            done += size
            if progress is not None:
                progress(done, m)
        self._blocks = []
        out.reverse()

        def cat(key: str, shape: tuple) -> np.ndarray:
            parts = [o.pop(key) for o in out]
            return np.concatenate(parts) if parts else np.zeros((0, *shape))

        k, kx = len(keep), len(xkeep)
        t = cat("t", ()).astype(np.int64)
        linked = cat("linked", ()).astype(bool)
        return Smoothed(t, cat("x", (kx,)), cat("P", (k, k)), cat("xs", (kx,)), cat("Ps", (k, k)), ~linked,
                        self.cov_states, self.x_states)  # fmt: skip
