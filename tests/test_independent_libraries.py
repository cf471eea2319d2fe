"""imurig against libraries it did not write: AllanTools (Allan deviation, IEEE 1139 / 952) and pymap3d
(WGS-84 geodetic, ECEF and NED conversions). Their code shares nothing with the project's; where the
project's closed forms and theirs compute the same quantity, the two agree to rounding."""
from __future__ import annotations

import allantools  # the test extra installs both
import numpy as np
import pymap3d
import pytest

from imurig.calibration.allan import allan_deviation, fit_arw
from imurig.flights.earth import (
    ecef_from_geodetic,
    geodetic_from_ecef,
    geodetic_from_ned,
    ned_from_geodetic,
)

EPS = np.finfo(float).eps


@pytest.mark.parametrize("kind", ["white", "random_walk", "flicker_ish"])
def test_allan_deviation_is_allantools_overlapping_adev(kind):
    """calibration.allan.allan_deviation against allantools.oadev (rate data, data_type="freq") at the same
    cluster times: the same estimator (overlapping, IEEE 952) in other arithmetic. Both difference the
    integrated angle, d_k = theta_(k+2m) - 2 theta_(k+m) + theta_k; each theta (a cumulative sum) carries
    rounding of order eps max|theta|, so the deviations agree to 8 eps (1 + max|theta| / rms(d)) relative
    (a random walk's angle is large beside its second differences: seen 281 eps at a condition of 261)."""
    rng = np.random.default_rng(7)
    fs, n = 100.0, 100_000
    x = rng.normal(size=n) * 1e-4
    if kind == "random_walk":
        x = x + np.cumsum(rng.normal(size=n)) * 1e-7
    elif kind == "flicker_ish":
        x = x + np.convolve(rng.normal(size=n), np.ones(200) / 200, mode="same") * 1e-4
    taus = np.array([0.01, 0.1, 1.0, 10.0, 100.0])
    ours = allan_deviation(x, fs, taus)
    t2, theirs, _, _ = allantools.oadev(x, rate=fs, data_type="freq", taus=taus)
    np.testing.assert_array_equal(t2, taus)
    theta = np.concatenate(([0.0], np.cumsum(x))) / fs
    cond = []
    for m in np.round(taus * fs).astype(int):
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        cond.append(np.max(np.abs(theta)) / np.sqrt(np.mean(d * d)))
    assert np.all(np.abs(ours / theirs - 1) <= 8 * EPS * (1 + np.array(cond)))


def test_the_arw_fit_reads_the_noise_allantools_reads():
    """White rate noise of density N: fit_arw's N and the one read off AllanTools' curve on the same
    taus agree to rounding, and both sit within the estimator's scatter of the injected N (the deviation at
    tau with n / m clusters has a relative sd ~ 1 / sqrt(2 (n / m - 1)); 4 sd at the longest tau, 10 s)."""
    rng = np.random.default_rng(11)
    fs, n, N = 200.0, 200_000, 3e-4                      # rad/s/sqrt(Hz)
    x = rng.normal(size=n) * N * np.sqrt(fs)
    est, taus, sig = fit_arw(x, fs)
    _, theirs, _, _ = allantools.oadev(x, rate=fs, data_type="freq", taus=taus)
    N_theirs = float(np.exp(np.mean(np.log(theirs) + 0.5 * np.log(taus))))
    assert abs(est / N_theirs - 1) < 64 * EPS
    m = taus[-1] * fs
    assert abs(est / N - 1) < 4 / np.sqrt(2 * (n / m - 1))


def _points(rng, k):
    lat = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, k)
    lon = rng.uniform(-np.pi, np.pi, k)
    h = rng.uniform(-500.0, 20_000.0, k)
    return lat, lon, h


def test_geodetic_ecef_both_ways_is_pymap3ds():
    """WGS-84 forward (closed form: the same arithmetic in another order, to a few eps of the Earth's radius)
    and inverse (Bowring's 5 passes here, pymap3d's own iteration: each converges below 1e-9 m, and the
    heights carry ~1e-9 m of rounding; seen: 3e-9 m)."""
    rng = np.random.default_rng(3)
    lat, lon, h = _points(rng, 2000)
    r = ecef_from_geodetic(lat, lon, h)
    x, y, z = pymap3d.geodetic2ecef(lat, lon, h, deg=False)
    np.testing.assert_allclose(r, np.stack([x, y, z], axis=-1), rtol=0, atol=16 * EPS * 6.4e6)
    la, lo, hh = geodetic_from_ecef(r)
    la2, lo2, hh2 = pymap3d.ecef2geodetic(r[:, 0], r[:, 1], r[:, 2], deg=False)
    assert np.max(np.abs(la - la2)) * 6.4e6 < 1e-8 and np.max(np.abs(lo - lo2)) * 6.4e6 < 1e-8
    assert np.max(np.abs(hh - hh2)) < 1e-8


def test_ned_offsets_are_pymap3ds():
    """Offsets of points up to 3 km in latitude and longitude from a reference, on the reference's NED axes,
    both ways, to 1e-8 m: differences of ECEF positions of 6.4e6 m carry ~1e-9 m of rounding, the inverse its
    iteration (seen: 3e-9 m)."""
    rng = np.random.default_rng(5)
    lat0, lon0, h0 = np.radians(52.0), np.radians(4.37), 10.0
    lat = lat0 + rng.uniform(-0.03, 0.03, 500)
    lon = lon0 + rng.uniform(-0.03, 0.03, 500)
    h = rng.uniform(0.0, 12_000.0, 500)
    d = ned_from_geodetic(lat, lon, h, lat0, lon0, h0)
    n, e, dd = pymap3d.geodetic2ned(lat, lon, h, lat0, lon0, h0, deg=False)
    np.testing.assert_allclose(d, np.stack([n, e, dd], axis=-1), rtol=0, atol=1e-8)
    la, lo, hh = geodetic_from_ned(d, lat0, lon0, h0)
    la2, lo2, hh2 = pymap3d.ned2geodetic(d[:, 0], d[:, 1], d[:, 2], lat0, lon0, h0, deg=False)
    assert np.max(np.abs(la - la2)) * 6.4e6 < 1e-8 and np.max(np.abs(hh - hh2)) < 1e-8
