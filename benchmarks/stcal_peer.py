"""stcal 1.20 as the benchmarks run it: jump detection and ramp fitting of one integration.

One place for the conventions the peer needs (``bench_jumps.py``, ``bench_snowballs.py``,
``bench_jump_recipes.py`` import it): its DQ names, its read noise (that of a difference
of two reads: ``read_noise * sqrt(2)`` for a read noise ``read_noise`` per read), gain 1,
one process.  stcal comes with the ``benchmark`` extra.
"""

import time

import numpy as np

#: stcal's DQ bits by name (JWST's)
FLAGS = {"GOOD": 0, "DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "NO_GAIN_VALUE": 8,
         "UNRELIABLE_SLOPE": 16, "PERSISTENCE": 32, "CHARGELOSS": 64, "REFERENCE_PIXEL": 128}


def run_stcal(cube, read_noise, frame_time, *, nframes=1, groupgap=0, saturated=None,
              algorithm="OLS_C", expand_large_events=False):
    """stcal's two-point detection then ``ramp_fit_data`` (``OLS_C``, optimal weighting), or
    its ``LIKELY`` fit (which searches the jumps itself), on ramps of equal groups.

    Parameters
    ----------
    cube : numpy.ndarray
        ``(groups, rows, columns)`` float32, electrons (gain 1).
    read_noise : float
        Read noise of one frame (e); stcal is given ``read_noise * sqrt(2)``.
    frame_time : float
        Seconds per frame.
    nframes, groupgap : int
        Frames averaged per group and dropped between groups.
    saturated : numpy.ndarray of bool, optional
        ``cube``'s saturated reads (stcal's SATURATED group flag).
    algorithm : {'OLS_C', 'LIKELY'}
    expand_large_events : bool
        stcal's snowball flagging (``JumpData.expand_large_events``).

    Returns
    -------
    dict
        ``slope``, ``err`` (float64), ``unusable`` (bool image), ``jumps`` (bool per
        group), ``time`` (detection and fit, s), ``fit_time`` (s).
    """
    from stcal.jump.jump import detect_jumps_data
    from stcal.jump.jump_class import JumpData
    from stcal.ramp_fitting.ramp_fit import ramp_fit_data
    from stcal.ramp_fitting.ramp_fit_class import RampData

    ngroups, ny, nx = cube.shape
    gain = np.ones((ny, nx), np.float32)
    noise = np.full((ny, nx), read_noise * np.sqrt(2), np.float32)  # a difference's
    gdq = np.zeros((1, *cube.shape), np.uint8)
    if saturated is not None:
        gdq[0][saturated] = FLAGS["SATURATED"]
    group_time = (nframes + groupgap) * frame_time
    t_detect = 0.0
    if algorithm == "OLS_C":
        jd = JumpData(gain2d=gain, rnoise2d=noise, dqflags=FLAGS)
        jd.init_arrays_from_arrays(cube[None].copy(), gdq, np.zeros((ny, nx), np.uint32))
        jd.nframes, jd.dt_group = nframes, np.ones(1) * group_time
        jd.n_reads_groupdiff = np.ones(1) * 2 * nframes
        jd.max_cores = "none"  # one process, like ours on the executor's threads
        jd.expand_large_events = expand_large_events
        t0 = time.perf_counter()
        gdq = detect_jumps_data(jd)[0]
        t_detect = time.perf_counter() - t0
    rd = RampData()
    rd.set_arrays(cube[None].copy(), gdq, np.zeros((ny, nx), np.uint32),
                  np.zeros((ny, nx), np.float32))
    rd.set_meta(name="NIRCAM", frame_time=frame_time, group_time=group_time,
                groupgap=groupgap, nframes=nframes, drop_frames1=None)
    rd.set_dqflags(FLAGS)
    rd.start_row, rd.num_rows = 0, ny
    if algorithm == "LIKELY":  # its covariance takes the frames of each group (from 1)
        step = nframes + groupgap
        rd.read_pattern = [list(range(1 + g * step, 1 + g * step + nframes))
                           for g in range(ngroups)]
    t1 = time.perf_counter()
    img = ramp_fit_data(rd, False, noise.copy(), gain, algorithm, "optimal", "none")[0]
    t2 = time.perf_counter()
    return {"slope": img["slope"], "err": img["err"].astype(np.float64),
            "unusable": (img["dq"] & FLAGS["DO_NOT_USE"]) != 0,
            "jumps": (gdq[0] & FLAGS["JUMP_DET"]) != 0, "time": t_detect + t2 - t1,
            "fit_time": t2 - t1}
