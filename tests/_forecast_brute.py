"""A brute-force noise forecast for tiny scenes, independent of the package's forecast engine.

Every sample a frame takes is a variable: each pixel of each read (read ``r``, column ``j``,
at sample ``starts[r] + o_j``) and each phantom sample (read ``r``, channel ``ch``, sample
``i`` at ``starts[r] - c + i``).  Their slope covariance is `slope_covariance` at every lag,
masked by what correlates (one channel for channel scope, one offset parity with ACN, the
samples a component is visible to).  A reduction is a matrix ``L`` from the variables to the
light-sensitive pixels, written here from the steps' definitions, and ``E[P(k)]`` is
``sum_i lambda_i P(v_i)`` over the eigenpairs of ``L C L^T``, each eigenvector pushed
through `power_spectrum` itself.
"""

import numpy as np

from spherex_reduce.analysis import power_spectrum
from spherex_reduce.analysis.light import light_sensitive
from spherex_reduce.noise.variance import slope_covariance


class Samples:
    """Index, sample time, channel, offset parity and kind of every sample of a frame."""

    def __init__(self, scene):
        s = scene.schedule
        g = s.geometry
        self.schedule, self.geometry = s, g
        nr, ncols, nch, c = s.n_reads, g.ncols, g.nchannels, s.phantom_reads
        self.npix = nr * ncols
        off = g.column_offsets()
        t_pix = (s.starts[:, None] + off[None, :]).ravel()
        ch_pix = np.broadcast_to(g.channel_of_column(), (nr, ncols)).ravel()
        par_pix = np.broadcast_to(off % 2, (nr, ncols)).ravel()
        i = np.arange(c)
        t_ph = (s.starts[:, None, None] - c + i[None, None, :]
                + np.zeros((1, nch, 1), int)).ravel()
        ch_ph = np.broadcast_to(np.arange(nch)[None, :, None], (nr, nch, c)).ravel()
        par_ph = np.broadcast_to((i - c) % 2, (nr, nch, c)).ravel()
        self.t = np.concatenate([t_pix, t_ph])
        self.chan = np.concatenate([ch_pix, ch_ph])
        self.parity = np.concatenate([par_pix, par_ph])
        self.is_pixel = np.arange(self.t.size) < self.npix

    def pixel(self, read, col):
        return read * self.geometry.ncols + col

    def phantom(self, read, ch):
        """Indices of the ``c`` phantom samples of ``read`` in channel ``ch``."""
        c, nch = self.schedule.phantom_reads, self.geometry.nchannels
        return self.npix + (read * nch + ch) * c + np.arange(c)

    def covariance(self, components):
        """``{name: C}`` over all samples."""
        s = self.schedule
        out = {}
        for comp in components:
            seen = np.where(self.is_pixel, comp.seen_by_pixels, comp.seen_by_phantom)
            lags, inverse = np.unique(np.abs(self.t[:, None] - self.t[None, :]),
                                      return_inverse=True)
            cov = slope_covariance(comp, s, lags)[0][inverse].reshape(self.t.size, -1)
            cov = cov * np.outer(seen, seen)
            if comp.scope == "channel":
                cov = cov * (self.chan[:, None] == self.chan[None, :])
            if comp.acn:
                cov = cov * (self.parity[:, None] == self.parity[None, :])
            out[comp.name] = cov
        return out


def read_time_covariance(samples, components, times):
    """``{name: C}`` over all samples when frame ``k`` is read at ``times[k]`` (s), from the
    definitions alone (not `slope_covariance`): each sample's slope is ``sum_k w_k x(t +
    s_k)``, ``w`` the least-squares weights of ``times``, ``s_k`` the time in whole samples,
    so two samples' slopes covary by ``-1/2 sum_jk w_j w_k D(t_b - t_a + s_k - s_j)``,
    ``D`` the component's structure function (the weights sum to zero)."""
    g = samples.geometry
    fs = g.pixel_rate
    times = np.asarray(times, dtype=float)
    w = (times - times.mean()) / np.sum((times - times.mean()) ** 2)
    starts = np.rint(times * fs)
    lag = samples.t[None, :] - samples.t[:, None]
    out = {}
    for comp in components:
        seen = np.where(samples.is_pixel, comp.seen_by_pixels, comp.seen_by_phantom)
        cov = np.zeros(lag.shape)
        for j in range(times.size):
            for k in range(times.size):
                cov -= 0.5 * w[j] * w[k] * comp.structure_function(lag + starts[k] - starts[j],
                                                                   fs)
        cov = cov * np.outer(seen, seen)
        if comp.scope == "channel":
            cov = cov * (samples.chan[:, None] == samples.chan[None, :])
        if comp.acn:
            cov = cov * (samples.parity[:, None] == samples.parity[None, :])
        out[comp.name] = cov
    return out


def reduction_matrix(samples, phantom=False, reference=None, reference_phantom=False,
                     side_columns=False):
    """``L``: the light-sensitive pixels (physical order, rows then columns) as combinations
    of the samples.  ``phantom``: minus the mean of the read's phantom samples of the
    pixel's channel; ``reference`` ``'mean'``: minus the mean over the channel's pixels of
    every reference read (each minus its read's phantom mean when ``reference_phantom``),
    ``'acn'`` the same per column-offset parity; ``side_columns``: the side reference
    columns of every active read are averaged too."""
    s, g = samples.schedule, samples.geometry
    rows, cols = light_sensitive(g)
    c = s.phantom_reads
    off = g.column_offsets()
    chan = g.channel_of_column()
    refs = np.flatnonzero(s.is_reference)
    light = [(p, j) for p in range(rows.start, rows.stop) for j in range(cols.start, cols.stop)]
    out = np.zeros((len(light), samples.t.size))
    for n, (p, j) in enumerate(light):
        r = np.flatnonzero((s.rows == p) & ~s.is_reference)[0]
        ch = chan[j]
        out[n, samples.pixel(r, j)] += 1.0
        if phantom and c:
            out[n, samples.phantom(r, ch)] -= 1.0 / c
        if reference is not None:
            group = [k for k in range(g.ncols) if chan[k] == ch
                     and (reference == "mean" or off[k] % 2 == off[j] % 2)]
            used = [(q, k) for q in refs for k in group]
            if side_columns:
                side = g.reference_column_mask()
                used += [(q, k) for q in np.flatnonzero(~s.is_reference) for k in group
                         if side[k]]
            w = 1.0 / len(used)
            for q, k in used:
                out[n, samples.pixel(q, k)] -= w
                if reference_phantom and c:
                    out[n, samples.phantom(q, ch)] += w / c
    return out


def expected_spectrum(samples, lmat, cov, bins):
    """``E[power_spectrum]`` of the image ``lmat @ x``, ``x`` of covariance ``cov``."""
    g = samples.geometry
    rows, cols = light_sensitive(g)
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    cy = lmat @ cov @ lmat.T
    lam, vec = np.linalg.eigh(cy)
    keep = lam > 1e-12 * max(lam.max(), 1e-300)
    total = 0.0
    for lv, v in zip(lam[keep], vec[:, keep].T, strict=True):
        total = total + lv * power_spectrum(v.reshape(shape), bins=bins)["power"].value
    return total


def wiener_matrix(samples, weights, acn, phantom=False, sides=None):
    """``L`` of a ``wiener`` correction: each light pixel minus (with ``phantom``, after its
    read's phantom mean) the estimate ``w @ y_ch + wd @ mean_ch(y)`` of its channel and
    group at its read; ``weights[g]`` is ``(w, wd, kind, uses_phantom)`` of group ``g`` and
    ``y`` the reference reads' group means (minus their phantom means for kind
    ``'subtracted'``) then, when used, every read's phantom mean.  ``sides[g]``, if given,
    is ``(ws, reads, [(channel, columns), ...])``: the estimate adds ``ws @ s``, ``s`` at
    each of ``reads`` the mean over those channels of their columns' mean (minus the
    channel's phantom mean for kind ``'subtracted'``)."""
    s, g = samples.schedule, samples.geometry
    rows, cols = light_sensitive(g)
    c, nch = s.phantom_reads, g.nchannels
    off, chan = g.column_offsets(), g.channel_of_column()
    refs = np.flatnonzero(s.is_reference)

    def observations(ch, grp, kind, use):
        members = [k for k in range(g.ncols) if chan[k] == ch
                   and (not acn or off[k] % 2 == grp)]
        out = []
        for q in refs:
            v = np.zeros(samples.t.size)
            for k in members:
                v[samples.pixel(q, k)] += 1.0 / len(members)
            if kind == "subtracted":
                v[samples.phantom(q, ch)] -= 1.0 / c
            out.append(v)
        if use:
            for r in range(s.n_reads):
                v = np.zeros(samples.t.size)
                v[samples.phantom(r, ch)] = 1.0 / c
                out.append(v)
        return np.array(out)

    obs = {(ch, grp): observations(ch, grp, *weights[grp][2:])
           for ch in range(nch) for grp in range(len(weights))}
    side_obs = {}
    for grp, (ws, reads, groups) in enumerate(sides or []):
        if ws is None:
            continue
        v = np.zeros((len(reads), samples.t.size))
        for i, q in enumerate(reads):
            for ch, columns in groups:
                for k in columns:
                    v[i, samples.pixel(q, k)] += 1.0 / (len(columns) * len(groups))
                if weights[grp][2] == "subtracted":
                    v[i, samples.phantom(q, ch)] -= 1.0 / (c * len(groups))
        side_obs[grp] = (ws, v)
    light = [(p, j) for p in range(rows.start, rows.stop) for j in range(cols.start, cols.stop)]
    out = np.zeros((len(light), samples.t.size))
    for n, (p, j) in enumerate(light):
        r = np.flatnonzero((s.rows == p) & ~s.is_reference)[0]
        ch, grp = chan[j], (off[j] % 2 if acn else 0)
        w, wd = weights[grp][:2]
        out[n, samples.pixel(r, j)] += 1.0
        if phantom and c:
            out[n, samples.phantom(r, ch)] -= 1.0 / c
        out[n] -= w[r] @ obs[ch, grp]
        if wd is not None:
            out[n] -= wd[r] @ (sum(obs[k, grp] for k in range(nch)) / nch)
        if grp in side_obs:
            ws, v = side_obs[grp]
            out[n] -= ws[r] @ v
    return out
