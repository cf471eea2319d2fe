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
