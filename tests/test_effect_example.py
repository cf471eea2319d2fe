"""The README's worked example: a new effect added as one file (examples/effects/air_conditioning.py)
is injected by the chain, found by the diagnosis, counted by the bounds, and scored against truth."""
from __future__ import annotations

import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import SMALL

from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.diagnose.tilt_table import diagnose_tilt_table
from imurig.kernel import random_streams
from imurig.montecarlo.tilt_crlb import window_noise_cov
from imurig.sensors.chain import ImuLab
from imurig.sensors.effects import ChainContext, for_view, registered

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "effects" / "air_conditioning.py"
START = "2005-06-14T17:50:00+02:00"  # the unit runs to 18:00 (its timetable), the pump stopped at 17:30
START_H = 17.0 + 50 / 60


def _example():
    spec = importlib.util.spec_from_file_location("air_conditioning_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses resolve annotations through the module
    spec.loader.exec_module(module)
    return module.AirConditioning


AirConditioning = _example()
AC = AirConditioning(rms_m_s2=5e-3)  # the diagnosis tests the timetable it knows: the defaults


@pytest.fixture(scope="module")
def records():
    # the lab's own effects run in the whole-record chain (simulate() falls back to it): the quiet lab
    # through the same chain, so that only the effect's own stream differs
    camp = TiltTableCampaign(protocol=SMALL, seed=11, start_time=START)
    table, lab, ss = camp.build()
    quiet = lab.measure(table.simulate(camp.protocol, camp.start_time,
                                       random_streams.generator("campaign/tilt-table/rig", camp.seed)), ss)
    return quiet, replace(camp, lab_effects=(AC,)).simulate()


def test_the_chain_injects_it_and_nothing_else(records):
    """While the unit is off, every sample is bit-identical to the lab without it (its own stream);
    while it runs, the added scatter is its rms times the sensitivity."""
    quiet, ac = records
    hours = START_H + (ac.time_s - ac.time_s[0]) / 3600.0
    off = ~AC.running(hours)
    assert off.any() and (~off).any()
    # the channel skew shifts each slot by the signal's slope, which at the switch-off sample still
    # sees the last running sample: compare samples whose neighbours are off too
    off &= np.roll(off, 1) & np.roll(off, -1)
    for ch in ("acc_x", "acc_y", "acc_z", "mag_x", "temp_box"):
        np.testing.assert_array_equal(ac.channels[ch][off], quiet.channels[ch][off])
    assert ac.truth["chain"]["effects"]["air_conditioning"]["rms_m_s2"] == 5e-3


def test_the_diagnosis_finds_it_with_its_size(records):
    """Registered, the effect's test runs on every axis: found where it was injected, with the
    refitted rms within 4 standard errors of the truth; not found in the lab without it."""
    quiet, ac = records
    with registered(AirConditioning):
        assert AirConditioning in for_view("position_scatter")
        found = diagnose_tilt_table(ac, np.random.default_rng(0))
        clean = diagnose_tilt_table(quiet, np.random.default_rng(0))
    assert AirConditioning not in for_view("position_scatter")  # the library is the seed's again
    truth = AC.fitted(ac.truth)["rms_m_s2"]
    for a in "xyz":
        f = found["axes"][a]["scatter"]["finding_air_conditioning"]
        p = next(q for q in f["parameters"] if q["name"] == "rms_m_s2")
        assert abs(p["estimate"] - truth) < 4 * p["std_error"], (a, p, truth)
        assert "finding_air_conditioning" not in clean["axes"][a]["scatter"]


def test_the_bound_counts_it():
    """The tilt table's window-mean covariance grows by exactly the effect's noise_variance times the
    true sensitivity squared on the diagonal."""
    lab = ImuLab()
    p = {"sample_rate_hz": 1000.0, "logging": "direct", "start_time": START}
    hours = np.array([START_H + 1 / 60, START_H + 20 / 60])  # one window with the unit on, one off
    base = window_noise_cov(p, lab, 4000, hours)
    with_ac = window_noise_cov(p, replace(lab, effects=(AC,)), 4000, hours)
    ctx = ChainContext(time_s=np.zeros(1), sample_rate_hz=1000.0, hour_of_day=hours, window_samples=4000)
    s = lab.accelerometers.k1_A_per_m_s2 * lab.accelerometers.load_resistor_ohm
    assert AC.noise_variance(ctx) > 0
    np.testing.assert_allclose(with_ac - base, np.diag(AC.noise_variance(ctx) * s**2), rtol=1e-12, atol=0)
