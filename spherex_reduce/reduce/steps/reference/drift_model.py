"""The kriging systems of the ``wiener`` strategy: one parity group's covariances and weights.

Every channel's observations (its reference reads and, when used, the phantom value
of every read) are split into their mean over channels and each channel's
departure from it.  The departures estimate each channel's own drift (the
``'channel'`` system: the channel-scope terms alone); the mean estimates the drift
all channels share (``'mean'``: the channel terms over the number of channels plus
the common ones).  With side reference columns, the mean's system also observes the
side value of every read (`~spherex_reduce.reduce.steps.reference.side_values`): the
common drift at every row, which the reference rows see only at the start and end of
a frame.  Weights are solved once per set of reference reads and kept; a read that
averages fewer pixels is a rank-``k`` update (`~spherex_reduce.noise.read_covariance.Kriging`).
"""

import threading
import warnings

import numpy as np
from astropy.utils.exceptions import AstropyUserWarning

from ....core.limits import check_size
from ....noise.read_covariance import Kriging

__all__ = ["DriftModel", "side_kind"]

#: Solved systems a model keeps (per kind of observation, channel count and system).
_MAX_WEIGHTS = 8


def side_kind(kind):
    """The kind of a side value when the reference reads are of ``kind``."""
    return "side" if kind == "pixels" else "side-subtracted"


class DriftModel:
    """The covariance of one parity group's read values, its lag tables and the weights
    already solved (per set of reference reads, side reads and pixel counts).

    Parameters
    ----------
    cov : `~spherex_reduce.noise.read_covariance.ReadCovariance`
        With the group's side offsets when side values are observed.
    """

    def __init__(self, cov):
        self.cov = cov
        self.n_reads = cov.schedule.n_reads
        self._lags, self._bases = {}, {}
        self._lock = threading.RLock()  # one solve per key, whatever thread asks first

    def lags(self, kind_a, kind_b, scale, channel_scale=1.0):
        """Covariance of values ``m`` reads apart, indexed by ``m + n_reads - 1``:
        ``channel_scale`` times the channel's terms plus ``scale`` times the common ones."""
        key = (kind_a, kind_b)
        with self._lock:
            if key not in self._lags:
                m = np.arange(-(self.n_reads - 1), self.n_reads)
                self._lags[key] = self.cov.colored(m, kind_a, kind_b)
            lag = self._lags[key]
        return channel_scale * lag["channel"] + scale * lag["common"]

    def _white(self, kind, npixels, scale, channel_scale=1.0):
        cov = self.cov
        return (channel_scale * cov.white(kind, npixels, "channel")
                + scale * cov.white(kind, npixels, "common"))

    def _system(self, kind, reads, n_used, n_group, scale, phantom, side=None):
        """Covariances (observations, observations-targets, targets) of the channel's terms
        plus ``scale`` times the common ones; ``side``: the reads of the side values (the
        ``'mean'`` system only, whose ``scale`` is the number of channels)."""
        off, n = self.n_reads - 1, self.n_reads
        t = np.arange(n)
        white_t = self._white(kind, n_group, scale)
        lag = self.lags(kind, kind, scale)
        k_oo = lag[reads[None, :] - reads[:, None] + off] + np.diag(
            self._white(kind, n_used, scale))
        k_ot = lag[t[None, :] - reads[:, None] + off] + (t[None, :] == reads[:, None]) * white_t
        k_tt = np.full(n, lag[off] + white_t)
        blocks = [(kind, reads, k_ot)]
        if phantom:
            blocks.append(("phantom", t, self.lags("phantom", kind, scale)[
                t[None, :] - t[:, None] + off]))
        if side is not None:
            sk = side_kind(kind)
            # the target of a light row's read is its light pixels' value: the side pixels'
            # own white noise is not part of it (their phantom value, once subtracted, is)
            shared = white_t - self._white("pixels", n_group, scale)
            blocks.append((sk, side, self.lags(sk, kind, scale)[t[None, :] - side[:, None] + off]
                           + (t[None, :] == side[:, None]) * shared))
        if len(blocks) == 1:
            return k_oo, k_ot, k_tt
        sizes = [b[1].size for b in blocks]
        edges = np.r_[0, np.cumsum(sizes)]
        c_oo = np.empty((edges[-1], edges[-1]))
        for i, (ka, ra, _) in enumerate(blocks):
            for j, (kb, rb, _) in enumerate(blocks[i:], start=i):
                if i == j == 0:
                    part = k_oo
                else:
                    # the side values' channel terms: the mean over side channels, times
                    # the channels the scaled system averages
                    chs = scale if ka == kb and ka.startswith("side") else 1.0
                    part = self.lags(ka, kb, scale, chs)[rb[None, :] - ra[:, None] + off]
                    if i == j:
                        part[np.arange(ra.size), np.arange(ra.size)] += self._white(
                            ka, n_group, scale, chs)
                c_oo[edges[i]:edges[i + 1], edges[j]:edges[j + 1]] = part
                if j != i:
                    c_oo[edges[j]:edges[j + 1], edges[i]:edges[i + 1]] = part.T
        c_ot = np.concatenate([b[2] for b in blocks])
        return c_oo, c_ot, k_tt

    def held_bytes(self):
        """Bytes of the arrays this model holds now (its lag tables and solved systems).
        Not under the model's lock, which a solve holds for a second or more: the
        snapshot of its tables is atomic (no Python code runs while the lists are made)."""
        return _array_bytes([list(self._lags.values()), list(self._bases.values())])

    def nbytes(self, nreference, phantom, nside=0):
        """Bytes the solve of one system allocates at its peak: its covariances (with the
        phantom values at every read and the side values: ``(k + n_reads + r)²``) and the
        `Kriging` of them."""
        n = float(self.n_reads)
        m = nreference + n * phantom + nside
        # and a block's temporary (the phantom values' n x n, the side values' r x n)
        parts = 8.0 * (m * m + m * n + max(n * n * phantom, nside * n))
        return parts + Kriging.nbytes(m, n, nreference, 1 + int(phantom) + int(nside > 0))

    def _base(self, strategy, kind, reads, n_group, nch, system, phantom, side):
        """The solved system of full reads (see `Kriging`): ``system`` is ``'channel'``
        (the deviations from the channel mean), ``'mean'`` (the channel mean) or
        ``'total'`` (one channel alone); ``side`` (the mean's only) or None."""
        key = (kind, reads.tobytes(), n_group, nch, system, phantom,
               None if side is None else side.tobytes())
        with self._lock:
            if key not in self._bases:
                self._bases[key] = self._build(strategy, kind, reads, n_group, nch, system,
                                               phantom, side)
                while len(self._bases) > _MAX_WEIGHTS:
                    self._bases.pop(next(iter(self._bases)))
            return self._bases[key]

    def _build(self, strategy, kind, reads, n_group, nch, system, phantom, side):
        nside = 0 if side is None else side.size
        extra = (f" and {self.n_reads} phantom values" if phantom else "") + (
            f" and {nside} side values" if nside else "")
        check_size(self.nbytes(reads.size, phantom, nside),  # before anything is allocated
                   f"correct_reference (wiener): the kriging solve of {self.n_reads} reads "
                   f"from {reads.size} reference reads{extra}")
        full = np.full(reads.size, float(n_group))
        scale = {"channel": 0, "mean": nch, "total": 1}[system]
        parts = self._system(kind, reads, full, n_group, scale, phantom, side)
        constants = np.r_[np.zeros(reads.size, int), np.ones(self.n_reads * phantom, int),
                          np.full(nside, 1 + int(phantom))]
        return Kriging(*parts, strategy.regularization, constants, nupdate=reads.size), scale

    def weights(self, strategy, kind, reads, n_used, n_group, nch, joint, phantom, side=None):
        """Weights ``(T, k [+ n_reads])`` of the channel deviations, the change for the
        channel mean (zero without ``joint``) and of the side values (``(T, r)``, or None),
        the predicted error variance of one channel's estimate and that of the pixel mean
        (the ``mean`` strategy) under the same model.  ``n_used`` (per reference read; 0:
        not usable) only adds white variance to the full-read system (a rank-``k``
        update).  The side values enter the channel mean's system only (``joint`` with
        more than one channel); the variance then leaves out how a side channel's own
        drift in them correlates with its departure from the mean."""
        cov = self.cov
        extra = {}
        for scope in ("channel", "common"):
            with np.errstate(divide="ignore", invalid="ignore"):  # n = 0: dropped (inf)
                extra[scope] = np.where(
                    n_used > 0, cov.white("pixels", n_used, scope) - cov.white(
                        "pixels", n_group, scope), np.inf)
        ws = None
        if joint and nch > 1:
            b1, _ = self._base(strategy, kind, reads, n_group, nch, "channel", phantom, None)
            b0, s0 = self._base(strategy, kind, reads, n_group, nch, "mean", phantom, side)
            w1, v1 = b1.weights(extra["channel"])
            w0, v0 = b0.weights(extra["channel"] + s0 * extra["common"])
            m = w1.shape[1]
            ws = None if side is None else w0[:, m:]
            out = (w1, w0[:, :m] - w1, ws, v0 / nch + (1 - 1 / nch) * v1)
        else:
            base, _ = self._base(strategy, kind, reads, n_group, nch, "total", phantom, None)
            w, v = base.weights(extra["channel"] + extra["common"])
            out = (w, None, None, v)
        mean_kind = "subtracted" if phantom else kind
        ok = n_used > 0
        m_oo, m_ot, m_tt = self._system(mean_kind, reads[ok], n_used[ok], n_group, 1, False)
        mean = n_used[ok] / n_used[ok].sum()
        mean_var = m_tt - 2 * mean @ m_ot + np.einsum("i,ij,j->", mean, m_oo, mean)
        return (*out, mean_var)

    def estimate(self, strategy, kind, reads, obs, n, n_group, phantom, out, side=None):
        """Estimates ``out (L, n_reads, nch)`` from the reference reads' values
        ``obs (L, k, nch)`` averaging ``n (L, k, nch)`` pixels, the phantom values
        ``(L, n_reads, nch)`` (or None) and the side values (None, or ``(reads, values
        (L, r))``); returns the predicted error variances of the first frame (this
        strategy's and the mean's).  Frames with the same pixel counts share their
        weights and one matrix product."""
        nch = obs.shape[2]
        use = phantom is not None
        side_reads, side_vals = (None, None) if side is None else side
        patterns = {}
        for f in range(obs.shape[0]):
            patterns.setdefault(n[f].tobytes(), []).append(f)
        first = None
        for frames in patterns.values():
            nf = n[frames[0]]
            y = obs[frames] if phantom is None else np.concatenate([obs[frames],
                                                                     phantom[frames]], axis=1)
            y = np.where(np.isfinite(y), y, 0.0)  # reads without pixels: weight 0
            # with side values, the same reads usable in every channel share one set of
            # weights, for the mean count of each read (a channel that lost a few pixels to
            # the clip has its white noise misstated by that fraction, in the weights
            # alone): the side values enter the joint estimate only
            same = nf == nf[:, :1] if side is None else (nf > 0) == (nf[:, :1] > 0)
            if same.all() and nf[:, 0].any():
                w, wd, ws, var, mvar = self.weights(strategy, kind, reads,
                                                    nf.mean(axis=1), n_group, nch,
                                                    True, use, side_reads)
                flat = np.moveaxis(y, 1, 0).reshape(y.shape[1], -1)  # (k [+ n], F * nch)
                est = (w @ flat).reshape(-1, len(frames), nch)
                if wd is not None:
                    est += (wd @ y.mean(axis=2).T)[:, :, None]
                if ws is not None:
                    est += (ws @ side_vals[frames].T)[:, :, None]
                out[frames] = np.moveaxis(est, 1, 0)
            else:  # a read usable in some channels only: each channel with its own counts
                # (and no side values)
                if side is not None:
                    warnings.warn(f"correct_reference (wiener): {len(frames)} frame(s) with "
                                  "a reference read usable in some channels only are "
                                  "estimated without the side values", AstropyUserWarning,
                                  stacklevel=3)
                var = mvar = np.full(self.n_reads, np.nan)
                solved = {}
                for c in range(nch):
                    if not nf[:, c].any():
                        continue  # no usable reference pixel: NaN, flagged by the kernel
                    key = nf[:, c].tobytes()  # channels with the same counts: same weights
                    if key not in solved:
                        solved[key] = self.weights(strategy, kind, reads,
                                                   nf[:, c].astype(float), n_group, nch,
                                                   False, use)
                    w, _, _, var, mvar = solved[key]
                    out[frames, :, c] = y[:, :, c] @ w.T
            if first is None or 0 in frames:
                first = (var, mvar)
        return first


def _array_bytes(value, seen=None):
    """Bytes of the numpy arrays in ``value`` (dicts, lists, tuples and objects' attributes,
    followed down, each object once)."""
    seen = set() if seen is None else seen
    if id(value) in seen:
        return 0
    seen.add(id(value))
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, dict):
        return sum(_array_bytes(v, seen) for v in value.values())
    if isinstance(value, (list, tuple)):
        return sum(_array_bytes(v, seen) for v in value)
    if hasattr(value, "__dict__"):
        return _array_bytes(vars(value), seen)
    return 0
