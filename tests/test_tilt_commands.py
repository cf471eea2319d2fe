"""The tilt table's servo commands made for the rows asked (rigs.tilt_schedule.CommandSchedule,
rigs.tilt_table.TableCommands) against the whole arrays they stand for, bit for bit."""
from __future__ import annotations

import numpy as np
import pytest

from imurig.kernel.units import DEG
from imurig.rigs.tilt_schedule import CommandSchedule, position_counts
from imurig.rigs.tilt_table import TableCommands, TiltTableProtocol

PROTO = TiltTableProtocol(theta_deg=(0, 35, 90), phi_deg=(0, 120, 250), runs=("z_down", "z_up"), dwell_s=0.5,
                          settle_s=0.3, slew_rate_deg_s=30, sample_rate_hz=1000.0)


def _setpoints(p):
    nt, nphi = len(p.theta_deg), len(p.phi_deg)
    return np.repeat(np.asarray(p.theta_deg, float) * DEG, nphi), np.tile(np.asarray(p.phi_deg, float) * DEG, nt)


def _whole_profile(p, set_theta, set_phi, dt):
    """The schedule's commands as one array, filled slew by slew and hold by hold (the law of the module doc:
    a slew of N samples at its sample j is p0 + (1 - cos(pi j / N)) / 2 (p1 - p0))."""
    s = CommandSchedule(p, set_theta, set_phi, dt)
    cmd = np.full((s.n, 2), np.nan)
    for a, length, p0, p1 in s._pieces:
        if p0 is None:
            cmd[a:a + length] = p1
        else:
            f = (1 - np.cos(np.pi * np.arange(1, length + 1) / length)) / 2
            np.multiply(f[:, None], p1 - p0, out=cmd[a:a + length])
            cmd[a:a + length] += p0
    return s, cmd


def test_schedule_rows_are_the_whole_profile_bit_for_bit():
    th, ph = _setpoints(PROTO)
    s, cmd = _whole_profile(PROTO, th, ph, 1e-3)
    assert not np.isnan(cmd).any()          # the slews and holds cover the run
    assert np.array_equal(s.rows(0, s.n), cmd)
    rng = np.random.default_rng(5)
    for lo, hi in [(0, 1), (s.n - 1, s.n), (0, 0)] + [tuple(sorted(rng.integers(0, s.n + 1, 2))) for _ in range(200)]:
        assert np.array_equal(s.rows(lo, hi), cmd[lo:hi]), (lo, hi)
    # each window is at rest at its position's set-point
    for (a, b), t, p in zip(s.windows, th, ph):
        assert np.array_equal(cmd[a:b], np.broadcast_to([t, p], (b - a, 2)))


@pytest.mark.parametrize("with_shift", [False, True])
def test_table_commands_are_the_repeated_arrays_bit_for_bit(with_shift):
    """ctrl = cmd + off, + each position's setting error repeated over its steps (+ its gear-clearance
    shift): the whole arrays the table's run made before; rows, single rows and the whole array agree."""
    th, ph = _setpoints(PROTO)
    s, cmd = _whole_profile(PROTO, th, ph, 1e-3)
    rng = np.random.default_rng(7)
    offs = [rng.normal(0, 1e-4, 2) for _ in range(2)]
    errs = [rng.uniform(-5e-5, 5e-5, (th.size, 2)) for _ in range(2)]
    shifts = [rng.normal(0, 1e-5, (th.size, 2)) for _ in range(2)]
    counts = position_counts(s.n, s.windows)
    expect = np.empty((2, s.n, 2))
    for b in range(2):
        c = expect[b]
        np.add(cmd, offs[b], out=c)
        c += np.repeat(errs[b], counts, axis=0)
        if with_shift:
            c += np.repeat(shifts[b], counts, axis=0)
    ctrl = TableCommands(s, offs, [(e, x) for e, x in zip(errs, shifts)] if with_shift else errs)
    assert ctrl.shape == expect.shape
    assert np.array_equal(ctrl.whole(), expect)
    for b in range(2):
        for lo, hi in [tuple(sorted(rng.integers(0, s.n + 1, 2))) for _ in range(50)]:
            assert np.array_equal(ctrl[b, lo:hi], expect[b, lo:hi])
        for i in (0, 1, s.n // 2, s.n - 1, -1):
            assert np.array_equal(ctrl[b, i], expect[b, i])
    with pytest.raises(IndexError):
        ctrl[0, 0:10:2]
