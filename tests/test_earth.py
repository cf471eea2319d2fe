"""WGS-84 Earth model and rotation helpers against closed forms and published constants."""
import numpy as np
import pytest
from imurig.flights import earth as E

D = np.pi / 180


def test_published_wgs84_derived_constants():
    # NIMA TR8350.2 tables 3.4 / 3.5 values; k is derived from gamma_e, gamma_p, which are
    # published to 10 decimals (relative rounding 5e-12), so k agrees to ~1e-11
    assert E.K_SOMIGLIANA == pytest.approx(0.00193185265241, abs=1e-11)
    assert E.M_GEODETIC == pytest.approx(0.00344978650684, abs=1e-14)
    assert E.B_M == pytest.approx(6356752.3142, abs=1e-4)
    assert E.E2 == pytest.approx(6.69437999014e-3, abs=1e-14)


def test_normal_gravity_equator_pole_and_height():
    g = E.normal_gravity(np.array([0.0, np.pi / 2, -np.pi / 2]), 0.0)
    np.testing.assert_allclose(g, [E.GAMMA_E_M_S2, E.GAMMA_P_M_S2, E.GAMMA_P_M_S2], rtol=2e-15)
    # 45 deg latitude from the published k and e^2 (independent of the derived constants)
    s2 = 0.5
    expect45 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999014 * s2)
    assert E.normal_gravity(45 * D) == pytest.approx(expect45, rel=1e-11)
    # and the 1980 International Gravity Formula series (truncation ~1e-6, GRS80 vs WGS-84 ~1e-6)
    assert E.normal_gravity(45 * D) == pytest.approx(9.780327 * (1 + 0.0053024 * s2 - 0.0000058), abs=5e-6)
    # free-air gradient at the equator: -2 gamma_e/a (1 + f + m)
    h = 1.0
    grad = (E.normal_gravity(0.0, h) - E.normal_gravity(0.0, 0.0)) / h
    expect = -2 * E.GAMMA_E_M_S2 / E.A_M * (1 + E.F + E.M_GEODETIC) + 3 * E.GAMMA_E_M_S2 / E.A_M ** 2
    assert grad == pytest.approx(expect, rel=1e-9)
    # vectorised, vector form points down
    lat = np.linspace(-1.5, 1.5, 7)
    gN = E.gravity_N(lat, np.full(7, 1000.0))
    assert gN.shape == (7, 3) and np.all(gN[:, :2] == 0) and np.all(gN[:, 2] > 9.7)


def test_radii_closed_form():
    R_N, R_E = E.radii(np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(R_N, [E.A_M * (1 - E.E2), E.A_M / np.sqrt(1 - E.E2)], rtol=1e-15)
    np.testing.assert_allclose(R_E, [E.A_M, E.A_M / np.sqrt(1 - E.E2)], rtol=1e-15)


def test_ecef_known_points_and_round_trip():
    r = E.ecef_from_geodetic(np.array([0.0, np.pi / 2]), np.array([0.0, 0.3]), np.array([0.0, 0.0]))
    np.testing.assert_allclose(r[0], [E.A_M, 0, 0], atol=1e-9)
    np.testing.assert_allclose(r[1], [0, 0, E.B_M], atol=1e-8)
    rng = np.random.default_rng(1)
    lat = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, 1000)
    lon = rng.uniform(-np.pi, np.pi, 1000)
    h = rng.uniform(-500, 40e3, 1000)
    lat2, lon2, h2 = E.geodetic_from_ecef(E.ecef_from_geodetic(lat, lon, h))
    assert np.max(np.abs(lat2 - lat)) < 1e-14
    assert np.max(np.abs(E.wrap_pi(lon2 - lon))) < 1e-14
    assert np.max(np.abs(h2 - h)) < 1e-8


def test_ned_offsets():
    lat0, lon0, h0 = 52 * D, 4.37 * D, 10.0
    R_N, _ = E.radii(lat0)
    d = E.ned_from_geodetic(lat0 + 1e-7, lon0, h0, lat0, lon0, h0)
    assert d[0] == pytest.approx(1e-7 * (R_N + h0), rel=1e-6) and abs(d[1]) < 1e-9
    d = E.ned_from_geodetic(lat0, lon0, h0 + 5.0, lat0, lon0, h0)
    np.testing.assert_allclose(d, [0, 0, -5.0], atol=1e-9)
    dN = np.array([[1000.0, -2000.0, 30.0], [0.0, 0.0, 0.0]])
    lat, lon, h = E.geodetic_from_ned(dN, lat0, lon0, h0)
    np.testing.assert_allclose(E.ned_from_geodetic(lat, lon, h, lat0, lon0, h0), dN, atol=1e-8)


def test_C_EN_is_rotation_and_transport_rate_is_its_derivative():
    # dC_EN/dt = C_EN [omega_EN_N x] along a trajectory with geodetic rates from v_N
    lat, lon, h = 52 * D, 4.37 * D, 3000.0
    v_N = np.array([120.0, -80.0, 5.0])
    dlat, dlon, _ = E.geodetic_rates(lat, h, v_N)
    dt = 1e-3
    Cp = E.C_EN(lat + dlat * dt, lon + dlon * dt)
    Cm = E.C_EN(lat - dlat * dt, lon - dlon * dt)
    C = E.C_EN(lat, lon)
    dC = (Cp - Cm) / (2 * dt)
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(C.T @ dC, E.skew(E.omega_EN_N(lat, h, v_N)), atol=1e-13)
    # Earth rate: magnitude and vertical component
    w = E.omega_IE_N(lat)
    assert np.linalg.norm(w) == pytest.approx(E.OMEGA_E_RAD_S, rel=1e-15)
    assert w[2] == pytest.approx(-E.OMEGA_E_RAD_S * np.sin(lat), rel=1e-15)


def test_rotation_helpers():
    rng = np.random.default_rng(2)
    n = 500
    roll = rng.uniform(-np.pi, np.pi, n)
    pitch = rng.uniform(-1.5, 1.5, n)
    yaw = rng.uniform(-np.pi, np.pi, n)
    q = E.q_from_euler(roll, pitch, yaw)
    C = E.C_from_q(q)

    def Rx(a):
        return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])

    def Ry(a):
        return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])

    def Rz(a):
        return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])

    for i in range(5):
        np.testing.assert_allclose(C[i], Rz(yaw[i]) @ Ry(pitch[i]) @ Rx(roll[i]), atol=1e-15)
    r2, p2, y2 = E.euler_from_q(q)
    np.testing.assert_allclose(np.c_[r2, p2, y2], np.c_[roll, pitch, yaw], atol=1e-12)
    q2 = E.q_from_C(C)
    np.testing.assert_allclose(np.abs(np.sum(q2 * q, axis=1)), 1.0, atol=1e-14)
    np.testing.assert_allclose(E.C_from_q(E.q_mult(q[:-1], q[1:])), C[:-1] @ C[1:], atol=1e-14)
    phi = rng.uniform(-1.5, 1.5, size=(n, 3)) * np.r_[np.full(n // 2, 1.0), np.full(n - n // 2, 1e-7)][:, None]
    np.testing.assert_allclose(E.rotvec_from_q(E.q_from_rotvec(phi)), phi, atol=1e-15, rtol=1e-12)
    # small-angle rotation: C ~ I + [phi x]
    p = np.array([1e-6, -2e-6, 3e-6])
    np.testing.assert_allclose(E.C_from_q(E.q_from_rotvec(p)), np.eye(3) + E.skew(p), atol=1e-11)
