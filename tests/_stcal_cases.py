"""stcal 1.20's ramp-fitting and jump test cases, re-created as data.

Each case is the input of one or more stcal tests (``tests/test_ramp_fitting.py``,
``test_ramp_fitting_cases.py``, ``test_jump_twopoint_difference.py``,
``test_jump.py``, ``test_ramp_fitting_cas22.py`` of spacetelescope/stcal) and
the values those tests assert, written out here as small arrays so that
``tests/reduce/steps/fit_ramp/test_stcal_cases.py`` runs them through our steps without
stcal.  The stcal tests a case re-creates are named in its ``stcal`` field.

Conventions (stcal's, translated by the test module):

- group DQ bits are stcal's: `GOOD` 0, `DNU` 1 (DO_NOT_USE), `SAT` 2
  (SATURATED), `JUMP` 4 (JUMP_DET);
- ``read_noise`` is stcal's read noise, the noise of the difference of two
  frames (stcal divides it by sqrt(2 nframes) per group): our per-read noise is
  ``read_noise / sqrt(2)``;
- ramps are listed pixel by pixel (one row of pixels), group values in order;
  ``ramps[k][p]`` is integration ``k``, pixel ``p``;
- a NaN expected slope is stcal's "no slope".

The stcal tests not re-created here, and why, are the table "Agreement with
stcal's test cases" in ``docs/reduction.rst``.
"""

from dataclasses import dataclass

import numpy as np

GOOD, DNU, SAT, JUMP = 0, 1, 2, 4  # stcal's group DQ bits
NAN = float("nan")


@dataclass(frozen=True)
class RampCase:
    """A ramp-fitting case: inputs and the values stcal's test asserts.

    ``slope``, ``dq`` and ``var_rnoise`` are per pixel, for the exposure (the
    integrations combined); ``err`` is given only where stcal's Poisson
    variance is the exact one (two-group segments, or no signal).
    ``snr_weighted``: stcal's segment slopes use weights that depend on the
    segment's signal to noise (its "optimal" OLS), ours are uniform, so the
    test compares the slope with uniform least squares on the same segments
    and records stcal's value (``slope``) for the side-by-side check.
    """

    stcal: tuple
    ramps: tuple
    flags: tuple
    group_time: float
    read_noise: float
    gain: float
    slope: tuple
    dq: tuple
    var_rnoise: tuple | None = None
    err: tuple | None = None
    nframes: int = 1
    groupgap: int = 0
    groups: tuple | None = None
    dark_current: float = 0.0
    snr_weighted: bool = False
    #: per-integration slopes and DQ as stcal asserts them (multi-integration cases)
    int_slope: tuple | None = None
    int_dq: tuple | None = None
    #: pixels whose stcal slope comes from a single group (not compared; see the docs)
    one_group: tuple = ()
    #: stcal's settings for the side-by-side run: suppress one-group ramps, and
    #: the instrument ("MIRI" drops first and last groups flagged DO_NOT_USE)
    suppress_one_group: bool = False
    instrument: str = "NIRSpec"

    @property
    def id(self):
        return self.stcal[0]

    @property
    def nints(self):
        return len(self.ramps)

    def cube(self, k=0):
        """Integration ``k`` as a (groups, 1, pixels) float32 cube and its stcal DQ."""
        data = np.array(self.ramps[k], dtype=np.float32).T[:, None, :]
        flags = np.array(self.flags[k], dtype=np.uint32).T[:, None, :]
        return data, flags


@dataclass(frozen=True)
class JumpCase:
    """A jump-detection case: one integration, the reads stcal flags JUMP_DET.

    ``jumps[p]`` are the groups of pixel ``p`` that must be flagged, and
    ``clean[p]`` those that must not (stcal's asserts; where a test asserts
    only that a jump was found, ``jumps[p]`` is None and ``any_jump`` is True).
    """

    stcal: tuple
    ramps: tuple
    read_noise: float
    jumps: tuple
    clean: tuple
    flags: tuple | None = None
    any_jump: bool = False
    gain: float = 1.0

    @property
    def id(self):
        return self.stcal[0]

    def cube(self):
        data = np.array(self.ramps, dtype=np.float32).T[:, None, :]
        flags = (np.zeros(data.shape, np.uint32) if self.flags is None
                 else np.array(self.flags, dtype=np.uint32).T[:, None, :])
        return data, flags


# -- test_ramp_fitting_cases.py: one 10-group ramp, group time 10 s, gain 5.5,
#    read noise 10.34; the same ramp with different group DQ
_CASES = "test_ramp_fitting_cases.py::"
_RAMP = (15.0, 25.0, 35.0, 54.0, 55.0, 65.0, 75.0, 94.0, 95.0, 105.0)
_G, _J, _S = GOOD, JUMP, SAT


def _nirspec(name, ramp, dq, slope, out_dq, var_r, snr=False, instrument="NIRSpec"):
    return RampCase((_CASES + name,), ((ramp,),), ((dq,),), 10.0, 10.34, 5.5, (slope,),
                    (out_dq,), (var_r,), snr_weighted=snr, instrument=instrument)


RAMP_CASES = [
    _nirspec("test_pix_0", _RAMP, (_G,) * 10, 1.0117551, GOOD, 0.00647973, snr=True),
    _nirspec("test_pix_1", _RAMP, (_G, _J, _J, _G) + (_S,) * 6, 1.8999999, JUMP | SAT,
             1.0691562),
    _nirspec("test_pix_2", _RAMP, (_G, _G, _G, _J, _G, _J, _G, _J, _S, _S), 0.850000023,
             JUMP | SAT, 0.1781927),
    _nirspec("test_pix_3", _RAMP, (_G,) * 8 + (_J, _G), 1.07484829, JUMP, 0.01257831, snr=True),
    _nirspec("test_pix_5", (15.0, 25.0, 35.0, 54.0, 2055.0, 2065.0, 2075.0, 2094.0, 2095.0,
                            2105.0), (_G,) * 4 + (_J,) + (_G,) * 5, 1.073401, JUMP, 0.02375903,
             snr=True),
    _nirspec("test_pix_6", (15.0, 25.0, 35.0, 54.0, 55.0, 65.0, 375.0, 394.0, 395.0, 405.0),
             (_G, _G, _J, _J) + (_G,) * 6, 6.104500, JUMP, 0.01875712, snr=True),
    _nirspec("test_pix_7", (15.0, 25.0, 35.0, 54.0, 55.0, 65.0, 75.0, 94.0, 195.0, 205.0),
             (_G,) * 8 + (_J, _J), 1.0757396, JUMP, 0.01272805, snr=True),
    _nirspec("test_pix_8", _RAMP, (_G, _J, _G, _G, _G, _G, _G, _S, _S, _S), 0.98561335,
             JUMP | SAT, 0.03054732, snr=True),
    _nirspec("test_pix_9", _RAMP, (_G, _G, _J, _J, _G, _G, _G, _G, _J, _G), 0.9999994, JUMP,
             0.048598),
    _nirspec("test_pix_10", _RAMP, (_G, _G, _J, _G, _G, _J, _G, _G, _G, _G), 1.0, JUMP,
             0.04276625),
    _nirspec("test_pix_11", _RAMP, (_G, _G) + (_S,) * 8, 1.0, SAT, 1.0691562),
    # two groups: the second saturated (a one-group slope), both saturated
    RampCase((_CASES + "test_pix_12",), (((15.0, 59025.0), (61000.0, 61000.0)),),
             (((GOOD, SAT), (SAT, SAT)),), 10.0, 10.34, 5.5, (1.5, NAN), (SAT, DNU | SAT),
             (1.069156, 0.0), one_group=(0,)),
    _nirspec("test_miri_0", (8888.0, *_RAMP[1:-1], 888.0), (DNU,) + (_G,) * 8 + (DNU,),
             1.025854, GOOD, 0.01272805, snr=True,
             instrument="MIRI"),
    _nirspec("test_miri_1", (7777.0, 125.0, 135.0, 154.0, 165.0, 175.0, 185.0, 204.0, 205.0,
                             777.0), (DNU | JUMP,) + (_G,) * 8 + (DNU,), 1.1996487, GOOD,
             0.01272805, snr=True,
             instrument="MIRI"),
    _nirspec("test_miri_2", (4444.0, *_RAMP[1:-1], 444.0), (DNU | JUMP,) + (_G,) * 8
             + (DNU | JUMP,), 1.025854, GOOD, 0.01272805, snr=True,
             instrument="MIRI"),
    _nirspec("test_miri_3", (6666.0, *_RAMP[1:-1], 666.0), (DNU,) + (_G,) * 8
             + (DNU | JUMP,), 1.025854, GOOD, 0.01272805, snr=True,
             instrument="MIRI"),
]

# -- test_ramp_fitting.py
_FIT = "test_ramp_fitting.py::"
# JP-2326: a MIRI ramp, read noise 1000 (signal to noise below 5: uniform weights)
_MIRI = (120.133545, 117.85222, 87.38832, 66.90588, 51.392555, 41.65941, 32.15081,
         24.25277, 15.955284, 9.500946)
_NEG = tuple(-0.5 * (k + 1) for k in range(10))
_ONES5 = (1.0, 2.0, 3.0, 4.0, 5.0)
_SAT5 = (SAT,) * 5
_NIRCAM = tuple(8000.0 + 2000.0 * k for k in range(5))

RAMP_CASES += [
    RampCase((_FIT + "test_miri_ramp_dnu_at_ramp_beginning",), ((_MIRI,),),
             (((DNU, DNU) + (GOOD,) * 7 + (DNU,),),), 2.77504, 1000.0, 5.5, (-4.1035075,),
             (None,), instrument="MIRI"),
    RampCase((_FIT + "test_miri_ramp_dnu_and_jump_at_ramp_beginning",), ((_MIRI,),),
             (((DNU, JUMP) + (GOOD,) * 7 + (DNU,),),), 2.77504, 1000.0, 5.5, (-4.9032097,),
             (None,), instrument="MIRI"),
    # two-group ramps with every DQ combination; the last three are one-group slopes
    RampCase((_FIT + "test_2_group_cases[OLS_C]",), (((-12328.601, -4289.051),) * 7,),
             (((GOOD, GOOD), (SAT, GOOD), (DNU | SAT, GOOD), (DNU, SAT), (DNU, GOOD),
               (GOOD, DNU), (GOOD, DNU | SAT)),), 14.58889, 9.4552, 0.9699,
             (551.0735, NAN, NAN, NAN, -293.9943, -845.0678, -845.0677),
             (GOOD, DNU | SAT, DNU | SAT, DNU | SAT, GOOD, GOOD, SAT),
             (0.420046, 0.0, 0.0, 0.0, 0.420046, 0.420046, 0.420046),
             err=(6.274218, NAN, NAN, NAN, 0.6481096, 0.6481096, 0.6481096),
             one_group=(4, 5, 6)),
    # group time 1 s, gain 1, read noise 10; 5 groups 1..5: all saturated, only
    # group 0 good (a one-group ramp, suppressed), all good
    RampCase((_FIT + "test_one_group_ramp_suppressed_one_integration[OLS_C]",),
             ((_ONES5,) * 3,), ((_SAT5, (GOOD, *_SAT5[1:]), (GOOD,) * 5),), 1.0, 10.0, 1.0,
             (NAN, NAN, 1.0000001), (DNU | SAT, DNU | SAT, GOOD), (0.0, 0.0, 4.999999),
             suppress_one_group=True),
    # the same with suppression off: the second pixel is a one-group slope
    RampCase((_FIT + "test_one_group_ramp_not_suppressed_one_integration[OLS_C]",),
             ((_ONES5,) * 3,), ((_SAT5, (GOOD, *_SAT5[1:]), (GOOD,) * 5),), 1.0, 10.0, 1.0,
             (NAN, 1.0, 1.0000001), (DNU | SAT, SAT, GOOD), (0.0, 100.0, 5.0000005),
             one_group=(1,)),
    # a falling ramp: no shot noise, the uncertainty is the read noise's
    RampCase((_FIT + "test_neg_med_rates_single_integration_slope",
              _FIT + "test_neg_med_rates_single_integration_integ",
              _FIT + "test_neg_med_rates_single_integration_optional"),
             ((_NEG,),), (((GOOD,) * 10,),), 1.0, 10.0, 1.0, (-0.5,), (GOOD,), (600.0 / 990.0,),
             err=(np.sqrt(600.0 / 990.0),)),
    # a falling ramp and a rising one (3 e per group) with jumps of 50
    # at groups 5 and 10: three segments, no shot noise on the falling one
    RampCase((_FIT + "test_neg_med_rates_single_integration_multi_segment_optional",),
             ((tuple(-0.5 * (k + 1) for k in range(15)),
               tuple(3.0 * (k + 1) + 50.0 * (k >= 5) + 50.0 * (k >= 10) for k in range(15))),),
             (((GOOD,) * 15, tuple(JUMP if k in (5, 10) else GOOD for k in range(15))),), 1.0,
             10.0, 1.0, (-0.5, 3.0), (GOOD, JUMP), err=(np.sqrt(600.0 / (15**3 - 15)), None)),
    # the falling ramp with a dark current of 1 e/s: stcal's Poisson variance 0.11
    # (to 2 decimals) is the dark current's
    RampCase((_FIT + "test_neg_with_avgdark",), ((_NEG,),), (((GOOD,) * 10,),), 1.0, 10.0, 1.0,
             (-0.5,), (GOOD,), (600.0 / 990.0,), dark_current=1.0),
    # NIRCam, 2 frames per group and a gap of 3 frames (group time 53.68 s):
    # all good, saturated from group 2, saturated from group 1 (a one-group slope)
    RampCase((_FIT + "test_only_good_0th_group[OLS_C]",), ((_NIRCAM,) * 3,),
             (((GOOD,) * 5, (GOOD, GOOD) + (SAT,) * 3, (GOOD,) + (SAT,) * 4),), 53.68, 10.0, 5.0,
             (37.257824, 37.257824, 496.77103), (GOOD, SAT, SAT),
             (0.00086759, 0.01735182, 0.19279794), nframes=2, groupgap=3, one_group=(2,)),
    # two jumps (165.855 and 430.543) on a 13.67 per group ramp: stcal asserts
    # their magnitudes (not recorded by fit_ramp); the slope is the ramp's
    RampCase((_FIT + "test_crmag",),
             ((tuple(13.67 * (k + 1) + 165.855 * (k >= 3) + 430.543 * (k >= 7)
                     for k in range(10)),
               tuple(13.67 * 1.34 * (k + 1) for k in range(10))),),
             ((tuple(JUMP if k in (3, 7) else GOOD for k in range(10)), (GOOD,) * 10),), 10.6,
             0.7071, 1.0, (13.67 / 10.6, 13.67 * 1.34 / 10.6), (JUMP, GOOD)),
]

# -- multi-integration cases (integrations combined)
_DNU5 = (DNU,) * 5
_INVALID = ((17343.719, 32944.32, 48382.062, 63066.062, 58844.7),
            (19139.965, 34863.45, 50415.816, 52806.453, 59525.01),
            (19020.926, 34759.785, 50351.984, 52774.695, 59533.586),
            (19060.592, 34772.496, 50247.75, 52781.04, 59509.086),
            (19011.01, 34768.832, 50247.547, 52829.46, 59557.85),
            (18939.426, 34680.39, 50175.406, 52685.527, 59486.184),
            (19009.908, 34748.207, 50274.14, 52723.406, 59523.812),
            (19072.715, 34844.24, 50421.906, 52781.83, 59527.06))
_INVALID_DQ = ((DNU, GOOD, JUMP, GOOD, DNU | SAT),) + ((DNU, GOOD, JUMP, SAT, DNU | SAT),) * 2 + (
    (DNU, GOOD, GOOD, SAT, DNU | SAT),) + ((DNU, GOOD, JUMP, SAT, DNU | SAT),) * 4

_BRAMP = (149.3061, 299.0544, 449.9949, 599.7617, 749.7327, 900.117, 1049.314, 1200.6003,
          1350.0906, 1500.7772, 1649.3098, 1799.8952, 1949.1304, 2100.1875, 2249.85, 2399.1154,
          2550.537, 2699.915, 2850.0734, 2999.7891)
_JUMPSAT = (GOOD,) * 5 + (JUMP, JUMP) + (GOOD,) * 8 + (SAT,) * 5

MULTI_CASES = [
    # NIRSpec, 4 frames per group, gap 1 (group time 53.68 s): the first
    # integration all DO_NOT_USE
    RampCase((_FIT + "test_dq_multi_int_dnu",),
             (((100.0, 200.0, 300.0, 400.0, 500.0),), ((100.0, 200.0, 300.0, 400.0, 500.0),)),
             ((_DNU5,), ((GOOD,) * 5,)), 53.68, 10.0, 5.0, (1.8628913,), (GOOD,), (0.0004338,),
             nframes=4, groupgap=1, int_slope=((NAN,), (1.8628913,)), int_dq=((DNU,), (GOOD,))),
    # ramps of 1.5, 3 and 4.5 per group, all groups saturated in both
    # integrations, in the first only, in neither
    RampCase((_FIT + "test_utils_dq_compress_final",),
             (tuple(tuple(b * (k + 1) for k in range(5)) for b in (1.5, 3.0, 4.5)),) * 2,
             ((_SAT5, _SAT5, (GOOD,) * 5), (_SAT5, (GOOD,) * 5, (GOOD,) * 5)),
             1.0, 10.0, 1.0, (NAN, 3.0, 4.5), (DNU | SAT, None, GOOD),
             int_dq=((DNU | SAT, DNU | SAT, GOOD), (DNU | SAT, GOOD, GOOD))),
    # JP-3004: eight MIRI integrations, two with a two-group segment
    RampCase((_FIT + "test_invalid_integrations[OLS_C]",), tuple((r,) for r in _INVALID),
             tuple((d,) for d in _INVALID_DQ), 2.77504, 6.097407, 5.5, (5434.022,),
             (JUMP | SAT,), (2.4139147,), suppress_one_group=True),
    # the suppressed one-group ramps of the first integration, a good second one
    RampCase((_FIT + "test_one_group_ramp_suppressed_two_integrations[OLS_C]",),
             ((_ONES5,) * 3,) * 2, ((_SAT5, (GOOD, *_SAT5[1:]), (GOOD,) * 5), ((GOOD,) * 5,) * 3),
             1.0, 10.0, 1.0, (1.0000001,) * 3, (SAT, SAT, GOOD), (4.999998, 4.999998, 2.4999995),
             int_slope=((NAN, NAN, 1.0000001), (1.0000001,) * 3),
             int_dq=((DNU | SAT, DNU | SAT, GOOD), (GOOD,) * 3), suppress_one_group=True),
    # the same with suppression off: the second pixel's first integration is a
    # one-group slope
    RampCase((_FIT + "test_one_group_ramp_not_suppressed_two_integrations[OLS_C]",),
             ((_ONES5,) * 3,) * 2, ((_SAT5, (GOOD, *_SAT5[1:]), (GOOD,) * 5), ((GOOD,) * 5,) * 3),
             1.0, 10.0, 1.0, (1.0000001,) * 3, (SAT, SAT, GOOD), (5.0, 4.7619047, 2.5000002),
             int_slope=((NAN, 1.0, 1.0000001), (1.0000001,) * 3),
             int_dq=((DNU | SAT, SAT, GOOD), (GOOD,) * 3), one_group=(1,)),
    # JP-2988, 20 groups of 4 frames and a gap of 1 (group time 53.68 s):
    # one integration good and one with two jumps and saturated from group 15;
    # that one and a saturated one; two saturated ones
    RampCase((_FIT + "test_new_saturation[OLS_C]",), ((_BRAMP,) * 3,) * 2,
             (((GOOD,) * 20, _JUMPSAT, (SAT,) * 20), (_JUMPSAT, (SAT,) * 20, (SAT,) * 20)),
             53.68, 10.0, 5.0, (2.794969, 2.795479, NAN), (JUMP | SAT, JUMP | SAT, DNU | SAT),
             (5.9019785e-06, 6.1970772e-05, 0.0), nframes=4, groupgap=1, snr_weighted=True,
             int_slope=((2.7949154, 2.795479, NAN), (2.795479, NAN, NAN)),
             int_dq=((GOOD, JUMP | SAT, DNU | SAT), (JUMP | SAT, DNU | SAT, DNU | SAT))),
    # three falling ramps (-0.5, -1, -1.5 per group): no shot noise anywhere
    RampCase((_FIT + "test_neg_med_rates_multi_integrations_slopes",
              _FIT + "test_neg_med_rates_multi_integration_integ",
              _FIT + "test_neg_med_rates_multi_integration_optional"),
             tuple(((tuple(-0.5 * n * (k + 1) for k in range(10)),)) for n in (1, 2, 3)),
             (((GOOD,) * 10,),) * 3, 1.0, 10.0, 1.0, (-1.0,), (GOOD,), (600.0 / 2970.0,),
             err=(np.sqrt(600.0 / 2970.0),), int_slope=((-0.5,), (-1.0,), (-1.5,))),
]

# -- jumps: test_jump_twopoint_difference.py (group time 1, electrons, stcal's
#    3-sigma thresholds; noise-free ramps) and test_jump.py
_TWO = "test_jump_twopoint_difference.py::"


def _one(names, ramp, read_noise, jumps, flags=None, clean=None, any_jump=False):
    """A one-pixel jump case; ``clean`` defaults to every usable group not in ``jumps``."""
    n = len(ramp)
    if clean is None:
        bad = set() if flags is None else {k for k, f in enumerate(flags) if f & (DNU | SAT)}
        clean = tuple(k for k in range(n) if k not in (jumps or ()) and k not in bad)
    return JumpCase(tuple(_TWO + s for s in names), (ramp,), read_noise,
                    (jumps,), (clean,), None if flags is None else (flags,), any_jump=any_jump)


_STEP10 = (10.0, 60.0, 60.0, 60.0, 60.0, 60.0, 60.0, 2115.0, 2115.0, 2115.0)

JUMP_CASES = [
    # its pixel with three finite reads, [10, 20, 530], is left out (see the docs)
    JumpCase((_TWO + "test_varying_groups",),
             ((10.0, 20.0, 30.0, 530.0, 540.0), (10.0, 20.0, 30.0, 530.0, NAN),
              (10.0, 520.0, NAN, NAN, NAN)), 8.0,
             ((3,), (3,), ()), ((0, 1, 2, 4), (0, 1, 2), (0, 1))),
    JumpCase((_TWO + "test_nocrs_noflux",), ((0.0,) * 4,) * 3, 10.0, ((),) * 3,
             ((0, 1, 2, 3),) * 3),
    _one(("test_5grps_cr3_noflux",), (10.0, 10.0, 1000.0, 1000.0, 1000.0), 10.0, (2,)),
    # its second integration (a 5-group ramp stepping at group 1)
    _one(("test_4grps_2ints_cr2_noflux",), (10.0, 1000.0, 1000.0, 1000.0, 1000.0), 10.0, (1,)),
    _one(("test_6grps_negative_differences_zeromedian",),
         (100.0, 90.0, 95.0, 105.0, 100.0, 100.0), 10.0, ()),
    _one(("test_5grps_cr2_negjumpflux",), (1000.0, 10.0, 10.0, 10.0, 10.0), 10.0, (1,)),
    _one(("test_4grps_cr2_noflux",), (10.0, 1000.0, 1000.0, 1000.0), 10.0, (1,)),
    _one(("test_6grps_cr2_nframe2",), (10.0, 500.0, 1002.0, 1001.0, 1005.0, 1015.0), 10.0,
         (1, 2)),
    _one(("test_5grps_twocrs_2nd_5thbig",), (10.0, 600.0, 600.0, 600.0, 2115.0), 10.0, (1, 4)),
    _one(("test_10grps_twocrs_2nd_8th_big", "test_10grps_twocrs_10percenthit"), _STEP10, 10.0,
         (1, 7)),
    _one(("test_5grps_cr2_negslope",), (100.0, 0.0, -200.0, -260.0, -360.0), 10.0, (2,)),
    # stcal asserts the jump; the other groups are clean by construction
    _one(("test_6grps_1cr",), (0.0, 10.0, 21.0, 33.0, 46.0, 1146.0), 10.0, (5,)),
    _one(("test_7grps_1cr",), (0.0, 10.0, 21.0, 33.0, 46.0, 60.0, 1160.0), 10.0, (6,)),
    _one(("test_8grps_1cr",), (0.0, 10.0, 21.0, 33.0, 46.0, 60.0, 1160.0, 1175.0), 10.0, (6,)),
    _one(("test_9grps_1cr_1sat",), (0.0, 10.0, 21.0, 33.0, 46.0, 60.0, 1160.0, 1175.0, 6175.0),
         10.0, (6,), flags=(GOOD,) * 8 + (SAT,)),
    _one(("test_10grps_1cr_2sat",),
         (0.0, 10.0, 21.0, 33.0, 46.0, 60.0, 1160.0, 1175.0, 6175.0, 6175.0), 10.0, (6,),
         flags=(GOOD,) * 8 + (SAT,) * 2),
    _one(("test_11grps_1cr_3sat",),
         (0.0, 20.0, 39.0, 57.0, 74.0, 90.0, 1160.0, 1175.0, 6175.0, 6175.0, 6175.0), 10.0, (6,),
         flags=(GOOD,) * 8 + (SAT,) * 3),
    _one(("test_11grps_0cr_3donotuse",),
         (0.0, 18.0, 39.0, 57.0, 74.0, 90.0, 115.0, 131.0, 150.0, 6175.0, 6175.0), 10.0, (),
         flags=(DNU,) + (GOOD,) * 8 + (DNU,) * 2),
    _one(("test_10grps_cr2_gt3sigma_2frames", "test_10grps_cr2_gt3sigma_2frames_offdiag"),
         (0.0,) + (32.0,) * 9, 5 * np.sqrt(2), (1,)),
]

# test_det_jump_sigma_clipping: integration 7 of a NIRISS dark pixel (9 groups,
# read noise 16.6), a jump of 1000 at group 3
_NIS_DARK = (35.92628, 100.91746, 146.84523, 191.37482, 223.67198, 284.9848, 321.36685,
             405.71707, 423.96967)
JUMP_CASES += [
    _one(("test_det_jump_sigma_clipping",),
         tuple(v + 1000.0 * (k >= 3) for k, v in enumerate(_NIS_DARK)), 16.613169, (3,)),
    # test_jump.py::test_nirspec_saturated_pix, its pixel with two unsaturated groups
    JumpCase(("test_jump.py::test_nirspec_saturated_pix",),
             ((8.25666812e05, -1.10471914e05, 1.95755371e02, 1.83118457e03, 1.72250879e03,
               1.81733496e03, 1.65188281e03),), 10.7, ((),), ((0, 1),),
             flags=((GOOD, GOOD) + (SAT,) * 5,)),
]

#: test_ramp_fitting_cas22.py::test_simulated_ramps: Roman resultants (reads of
#: 3.04 s averaged in groups of 4, 1, 3, 10, 3 and 15), 100 e/s, read noise 5 e
CAS22_READ_PATTERN = ((1, 2, 3, 4), (5,), (6, 7, 8), tuple(range(9, 19)), (19, 20, 21),
                      tuple(range(22, 37)))
CAS22_READ_TIME, CAS22_FLUX, CAS22_READ_NOISE = 3.04, 100.0, 5.0
#: test_jump_cas22.py::test_find_jumps: the jump (e) at a random read of every pixel
CAS22_JUMP = 1000.0
