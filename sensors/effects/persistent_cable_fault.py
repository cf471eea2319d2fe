"""An intermittent contact that holds an offset for whole positions: a random-telegraph offset on
one analog line (seed 4.3.3 and Tab. 4.2), unlike the short spikes of ``cable_fault_spikes``.

    v(t) = a s(t),  s(t) in {0, 1}                                          [V],  on ``channel`` only

s: a two-state Markov process in continuous time (the contact open, s = 1, or closed, s = 0), with
exponential dwell times of means tau_1 (``dwell_open_s``) and tau_0 (``dwell_closed_s``), longer
than a position (15 s in the seed), started in its stationary law: P(s = 1) = p = tau_1 / (tau_0 +
tau_1), and the first dwell exponential too (memoryless), so s is stationary from the first sample.
Time is the record's own (``ctx.time_s``), so a remount gap counts as time. Stage "analog"
(stream "cable_contact"). Off by default.

Why the medians do not remove it (Tab. 4.2: sigma_y 0.3685 m/s^2 on raw data and 0.3695 after the
per-position medians, while x and z fell 7x): a position's samples share one state almost always,
so the median keeps the offset. Prior: sigma = a sqrt(p (1 - p)) = 0.3695 m/s^2, i.e. a = 0.739
m/s^2 = 0.0751 V through the Q-Flex's nominal 0.1017 V/(m/s^2) at p = 1/2.

Variance on its line (autocovariance a^2 p (1 - p) exp(-|dt| / tau_c), 1 / tau_c = 1 / tau_0 + 1 / tau_1):
per sample a^2 p (1 - p); the mean of N consecutive samples at 1 / f_s, with rho = exp(-1 / (f_s tau_c)),

    a^2 p (1 - p) / N^2 [N + 2 rho (N - N rho - 1 + rho^N) / (1 - rho)^2]      (exact, stationary)

which stays near a^2 p (1 - p) while N / f_s << tau_c: a window mean does not average it out.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from imurig.kernel import random_streams
from imurig.kernel.errors import ConfigError
from imurig.sensors.effects.base import ChainContext, Effect, Param

random_streams.register("sensor-chain/cable_contact", "the intermittent contact's telegraph switching",
                        child=True)

#: the seed's Tab. 4.2 sigma of the y channel after the medians (m/s^2) and the Q-Flex's nominal
#: sensitivity 1.33 mA/g x 750 ohm (V per m/s^2)
SEED_SIGMA_Y_M_S2 = 0.3695
NOMINAL_SENSITIVITY_V_PER_M_S2 = 1.33e-3 / 9.80665 * 750.0


def telegraph(duration_s: float, dwell_open_s: float, dwell_closed_s: float,
              rng: np.random.Generator) -> tuple[int, np.ndarray]:
    """(s_0, switch times (k,) s in (0, duration]) of the stationary telegraph (module doc)."""
    p = dwell_open_s / (dwell_open_s + dwell_closed_s)
    state = int(rng.random() < p)
    s0, t, switches = state, 0.0, []
    while True:
        t += rng.exponential(dwell_open_s if state else dwell_closed_s)
        if t > duration_s:
            return s0, np.asarray(switches, float)
        switches.append(t)
        state = 1 - state


def telegraph_state(t_rel: np.ndarray, s0: int, switches: np.ndarray) -> np.ndarray:
    """s (n,) in {0, 1} at the times t_rel (s from the start) for the start state and switch times."""
    return ((s0 + np.searchsorted(switches, np.asarray(t_rel, float), side="right")) % 2).astype(float)


@dataclass
class PersistentCableFault(Effect):
    """An intermittent contact on ``channel``: offset ``offset_V`` while open (telegraph dwell times)."""

    enabled: bool = False
    channel: str = "acc_y"
    offset_V: float = 2 * SEED_SIGMA_Y_M_S2 * NOMINAL_SENSITIVITY_V_PER_M_S2
    dwell_open_s: float = 60.0
    dwell_closed_s: float = 60.0

    name: ClassVar[str] = "persistent_cable_fault"
    stage: ClassVar[str] = "analog"
    stream: ClassVar[str] = "cable_contact"
    physics: ClassVar[str] = ("an intermittent contact in the y channel's cable holds an offset for whole positions, "
                              "so the per-position medians keep it")
    seed_section: ClassVar[str] = "4.3.3, Tab. 4.2"
    seed_says: ClassVar[str] = ("Tab. 4.2: sigma_y 3.685e-1 on raw data and 3.695e-1 after the medians, while x and z "
                                "fell from 2.4e-2 to 3e-3; the cabling test found the y channel's connector at fault")
    params: ClassVar[tuple] = (
        Param("offset_V", "V", seed=2 * SEED_SIGMA_Y_M_S2 * NOMINAL_SENSITIVITY_V_PER_M_S2,
              note="a sqrt(p(1-p)) = 0.3695 m/s^2 (Tab. 4.2) at p = 1/2, through the nominal sensitivity"),
        Param("dwell_open_s", "s", note="assumed; longer than a 15 s position"),
        Param("dwell_closed_s", "s", note="assumed; longer than a 15 s position"))

    def open_probability(self) -> float:
        """p = tau_1 / (tau_0 + tau_1)."""
        return self.dwell_open_s / (self.dwell_open_s + self.dwell_closed_s)

    def correlation_time_s(self) -> float:
        """tau_c = 1 / (1 / tau_0 + 1 / tau_1)."""
        return 1.0 / (1.0 / self.dwell_open_s + 1.0 / self.dwell_closed_s)

    def voltage(self, time_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """v (n,) V (module doc)."""
        t = np.asarray(time_s, float) - float(time_s[0])
        s0, switches = telegraph(float(t[-1]), self.dwell_open_s, self.dwell_closed_s, rng)
        return self.offset_V * telegraph_state(t, s0, switches)

    def lines(self, names, ctx: ChainContext | None = None) -> list[str]:
        if not self.enabled:
            return []
        if self.channel not in names:
            raise ConfigError(f"persistent cable fault on '{self.channel}', which is not an analog line of this "
                              f"record; choose one of {sorted(names)}")
        return [self.channel]

    def inject(self, v: np.ndarray, ctx: ChainContext, rng: np.random.Generator) -> np.ndarray:
        if not self.enabled:
            return v
        return v + self.voltage(ctx.time_s, rng)

    def noise_variance(self, ctx: ChainContext) -> float:
        """Variance (V^2) on its line of one sample or of the mean of ctx.window_samples (module doc)."""
        if not self.enabled:
            return 0.0
        p = self.open_probability()
        var = self.offset_V**2 * p * (1 - p)
        N = int(ctx.window_samples)
        if N <= 1:
            return var
        rho = float(np.exp(-1.0 / (ctx.sample_rate_hz * self.correlation_time_s())))
        tail = 2 * rho * (N - N * rho - 1 + rho**N) / (1 - rho) ** 2
        return var * (N + tail) / N**2

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{offset_V, open_probability} on ``channel`` (0 on the other lines or with the contact sound)."""
        e = truth["chain"].get("effects", {}).get(self.name)
        if not e or not e["enabled"] or (channel is not None and channel != e["channel"]):
            return {"offset_V": 0.0, "open_probability": 0.0}
        f = PersistentCableFault(**e)
        return {"offset_V": float(f.offset_V), "open_probability": f.open_probability()}
