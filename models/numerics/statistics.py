"""Statistics of residuals that are correlated in time (a model's error spans many samples)."""
from __future__ import annotations

import numpy as np


def effective_samples(residual: np.ndarray) -> float:
    """Number of independent residuals: N / (1 + 2 sum of autocorrelations), summed over the signals.

    The sum stops at the first pair of lags whose autocorrelations add up to a negative number
    (Geyer's initial positive sequence, as in MCMC effective sample sizes). The signals' transforms are taken
    together: rows of a contiguous array give the same numbers as one signal at a time, in one call.
    """
    columns = np.ascontiguousarray(np.atleast_2d(residual.T))
    n = columns.shape[1]
    centred = columns - columns.mean(axis=1, keepdims=True)
    spectrum = np.fft.rfft(centred, 2 * n, axis=1)
    total = 0.0
    for acf in np.fft.irfft(spectrum * np.conj(spectrum), axis=1)[:, :n]:
        if acf[0] <= 0:
            total += n
            continue
        acf = acf / acf[0]
        pairs = acf[0:n - 1:2] + acf[1:n:2]
        negative = np.flatnonzero(pairs < 0)
        kept = pairs[:negative[0]] if negative.size else pairs
        tau = float(np.cumsum(np.concatenate([[-1.0], 2 * kept]))[-1])  # -1 + 2 pair + 2 pair ..., in that order
        total += n / max(tau, 1.0)
    return total
