"""The filter's sensor-error states are named once, from the effect library, and their truth is
read from the same parameters the sensor models inject (issue 15: one name in truth, filter and
diagnosis)."""
import numpy as np

from imurig.flights.filter_config import FilterConfig
from imurig.sensors import error_states as es
from imurig.sensors.chain import ImuLab
from imurig.sensors.effects import LIBRARY, by_name

NON_EFFECT_SOURCES = {"temperature_sensor", "position_error", "compass"}


def _full_config() -> FilterConfig:
    return FilterConfig(estimate_scale_factors=True, estimate_misalignments=True, estimate_nonlinearity=True,
                        estimate_thermal_terms=True, gps_pos_states=True, gps_pos_tau_s=100.0,
                        gyro_bias_gm_states=True, mag_iron_states=True)


def test_every_sensor_error_state_names_a_library_effect():
    cfg = _full_config()
    names = cfg.state_names()
    assert len(names) == cfg.n_states == len(set(names))
    library = {c.name for c in LIBRARY}
    for n in names[9:]:
        sensor, source, param = n.split(".")
        assert sensor in {"acc", "gyro", "mag", "gps"}, n
        assert source in library or source in NON_EFFECT_SOURCES, n
        if source in library:
            assert by_name(source).stage == "sensor", n


def test_block_truth_is_what_the_sensor_models_inject():
    """Each block's truth equals the parameter of the effect object the sensor model composes."""
    lab = ImuLab.draw(np.random.default_rng(2005))
    acc, gyro = lab.accelerometers, lab.gyros
    ta, tg = acc.truth(), gyro.truth()
    eff = {type(e).name: e for e in acc.sensor_effects()}
    M = eff["axis_misalignment"].misalignment_rad
    assert np.array_equal(es.ACC_MISALIGNMENT.truth(ta), [M[i, j] for i, j in es.MIS_PAIRS])
    assert np.array_equal(es.ACC_NONLINEARITY.truth(ta), eff["scale_nonlinearity"].k2_per_m_s2)
    assert np.array_equal(es.ACC_BIAS.truth(ta), acc.bias_m_s2)
    assert np.array_equal(es.GYRO_BIAS.truth(tg), gyro.bias_rad_s)
    np.testing.assert_allclose(es.ACC_SCALE.truth(ta) + 1,
                               acc.k1_A_per_m_s2 * acc.load_resistor_ohm / acc.nominal_sensitivity_V_per_m_s2(),
                               rtol=1e-15)
    np.testing.assert_allclose(es.GYRO_SCALE.truth(tg) + 1, gyro.scale_V_per_rad_s / gyro.nominal_sensitivity(),
                               rtol=1e-15)
    assert np.array_equal(es.ACC_THERMAL[0].truth(ta), acc.bias_tempco_m_s2_per_K)
    # drawn errors are not zero, so the comparisons above can fail
    assert np.all(es.ACC_BIAS.truth(ta) != 0) and np.all(es.ACC_MISALIGNMENT.truth(ta) != 0)


def test_noise_effects_feed_the_filter_priors():
    """ImuNoise.from_sensors takes its densities from the noise effects: VRW = sqrt(sum rms^2/(2 hi))/K1
    over the current-noise bands reaching DC; ARW and bias instability from the gyro-noise effect."""
    from imurig.flights.filter_config import ImuNoise
    lab = ImuLab.draw(np.random.default_rng(7))
    acc, gyro = lab.accelerometers, lab.gyros
    fs = 1000.0
    noise = ImuNoise.from_sensors(acc, gyro, fs)
    # sampled directly: the band at DC keeps rms^2/(2 hi); a band wholly above fs/2 aliases to white
    # noise over (0, fs/2), density rms^2/fs; the 10-500 Hz band adds nothing at DC
    (lo0, hi0, r0), _, (lo2, hi2, r2) = acc.noise_bands
    assert lo0 == 0 and lo2 >= fs / 2
    dens2 = r0**2 / (2 * hi0) + r2**2 / fs
    np.testing.assert_allclose(noise.vrw, np.sqrt(dens2) / np.min(acc.k1_A_per_m_s2), rtol=1e-14)
    assert noise.arw == gyro.noise().arw_rad_s_per_sqrt_hz == gyro.arw_rad_s_per_sqrt_hz
    assert noise.gyro_bias_sigma == gyro.bias_instability_rad_s
