"""Numbers quoted from the paper (Heaton et al.), the independent expectations of tests."""

#: Table 2: (alpha e^2/Hz, beta e^2, gamma e^2 Hz^0.3) of each noise component
TABLE2 = {
    "video8": (3.71e-5, 8.40e-3, 0.0),
    "roic": (1.97e-3, 0.0, 1e-1),
    "bias_correlated": (0.0, 8.80e-5, 0.0),
    "bias_phantom_only": (0.0, 3.64e-6, 0.0),
    "bias_pixels_only": (2.91e-6, 3.07e-7, 0.0),
}
