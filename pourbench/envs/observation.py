"""The weight observation as on the robot: tared sensor force, noise, Butterworth low-pass.

The receiving container's force sensor is sampled at ``rate_hz`` (100 Hz), Gaussian noise of
standard deviation ``noise_n`` (the SensONE's 0.15 N resolution) is added, and each sample
goes through a 2nd-order Butterworth low-pass (1 Hz cut-off) designed with
:func:`scipy.signal.butter`. The filter runs one sample at a time for every world: the
sections' transposed direct form II (the recurrence :func:`scipy.signal.sosfilt` computes,
written out here because sosfilt's checks cost ~70 µs a call, a twentieth of a Pour-v0 step,
for one sample).

The noise of world ``k``'s ``i``-th sample is :func:`counter_normals` of the world's key
(drawn from its generator at reset) and ``i``: a pure function of the two, so every world's
noise is drawn in one array operation and does not depend on which other worlds share its
batch or process.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

GRAVITY = 9.81
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def _mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser over a uint64 array (wrapping arithmetic)."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def counter_normals(key: np.ndarray, counter: np.ndarray) -> np.ndarray:
    """Standard-normal draws, element ``i`` a pure function of ``(key[i], counter[i])``.

    Two SplitMix64 hashes of the pair give two uniforms, Box-Muller turns them into one
    normal. Same shapes in and out; uint64 inputs.
    """
    key = np.asarray(key, np.uint64)
    c = np.asarray(counter, np.uint64) * np.uint64(2)
    with np.errstate(over="ignore"):
        base = _mix64(key + _GOLDEN)
        h1 = _mix64(base ^ (c * _GOLDEN + _GOLDEN))
        h2 = _mix64(base ^ ((c + np.uint64(1)) * _GOLDEN + _GOLDEN))
    scale = 2.0**-53
    u1 = ((h1 >> np.uint64(11)).astype(np.float64) + 1.0) * scale  # (0, 1]
    u2 = (h2 >> np.uint64(11)).astype(np.float64) * scale  # [0, 1)
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(2.0 * np.pi * u2)


class WeightFilter:
    """Batched tared, noisy, low-passed weight (g) of ``num_worlds`` force sensors.

    Args:
        rate_hz: sampling rate, Hz.
        cutoff_hz: low-pass cut-off, Hz.
        order: Butterworth order.
        noise_n: noise standard deviation, N (0 disables it).
    """

    def __init__(
        self,
        num_worlds: int,
        rate_hz: float = 100.0,
        cutoff_hz: float = 1.0,
        order: int = 2,
        noise_n: float = 0.15,
    ) -> None:
        self.rate_hz, self.noise_n = float(rate_hz), float(noise_n)
        self.sos = signal.butter(order, cutoff_hz, btype="low", fs=rate_hz, output="sos")
        self.zi = np.zeros((self.sos.shape[0], num_worlds, 2))
        self.tare_n = np.zeros(num_worlds)
        self.value_g = np.zeros(num_worlds)

    def reset(self, world: int, force_n: float) -> None:
        """Tare world ``world`` at sensor reading ``force_n`` (N); the filter starts at 0 g."""
        self.tare_n[world] = force_n
        self.zi[:, world, :] = 0.0
        self.value_g[world] = 0.0

    def sample(self, worlds: np.ndarray, force_n: np.ndarray, noise: np.ndarray) -> None:
        """Feed one sensor sample to each of ``worlds``.

        Args:
            worlds: (k,) world indices sampled now.
            force_n: (k,) sensor readings (vertical force on the scale), N.
            noise: (k,) standard-normal draws, scaled here by ``noise_n``.
        """
        if len(worlds) == 0:
            return
        grams = (force_n - self.tare_n[worlds] + self.noise_n * noise) / GRAVITY * 1e3
        x = np.where(np.isfinite(grams), grams, 0.0)
        for (b0, b1, b2, _, a1, a2), z in zip(self.sos, self.zi, strict=True):
            z0, z1 = z[worlds, 0], z[worlds, 1]
            y = b0 * x + z0
            z[worlds, 0] = b1 * x - a1 * y + z1
            z[worlds, 1] = b2 * x - a2 * y
            x = y
        self.value_g[worlds] = x
