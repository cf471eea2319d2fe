"""Shared, session-scoped simulated datasets (small protocols that keep the suite fast)."""
from __future__ import annotations

import pytest

from imurig.campaigns.tilt_table import TiltTableCampaign
from imurig.rigs.tilt_table import TiltTableProtocol

#: A reduced protocol: 4 tilt angles x 6 rotations x 2 mountings, 4 s per position.
SMALL = TiltTableProtocol(theta_deg=(0, 30, 60, 90), phi_deg=(0, 60, 120, 180, 240, 300), dwell_s=4.0,
                          settle_s=1.0, slew_rate_deg_s=30.0)


def small_campaign(**kw) -> TiltTableCampaign:
    kw.setdefault("protocol", SMALL)
    return TiltTableCampaign(**kw)


@pytest.fixture(scope="session")
def small_recording():
    """A simulated small tilt-table recording (evening: pump off by the clock)."""
    return small_campaign(seed=11).simulate()


@pytest.fixture(scope="session")
def short_flight():
    """~43 s airborne at 100 Hz: level, 3-2-1-1, double doublet, S-turns at 30 deg both sides."""
    from imurig.flights.plan import AlphaDotSTurns, DoubleDoublet, Elevator3211, FlightPlan, Level, simulate_flight
    plan = FlightPlan(phases=(Level(3.0), Elevator3211(free_s=4.0), DoubleDoublet(lead_s=1.0, free_s=3.0, level_s=1.0),
                              AlphaDotSTurns(banks_first_deg=(30.0,), banks_second_deg=(30.0,), hold_s=5.0,
                                             after_s=2.0, level_s=2.0)))
    return simulate_flight(plan, progress_bar=False)


@pytest.fixture(scope="session")
def check_concealed_case():
    """``check(case, seed, size)``: the diagnosis of the case's recording names exactly the
    expected (channel, effect) pairs with the first parameter within 4 SE of the injected
    truth, and the case's null recording comes back clean. Returns the diagnosis and recording."""
    from imurig.concealed.suite import diagnose_case, found_effects, null_recording

    def check(case, seed: int, size: float):
        rec = case.make(seed, size)
        d = diagnose_case(case, rec, seed)
        assert found_effects(d) == case.expected
        est, se = case.found_param(d)
        assert abs(est - case.truth_param(rec)) < 4 * se
        assert found_effects(diagnose_case(case, null_recording(case, seed), seed, null=True)) == set()
        return d, rec

    return check
