"""Cross-coupling of the other two axes (seed 4.3.5, Table 4.5: product terms a_x a_z ...).

    a_j' = a_j + c_j a_k a_l          [m/s^2],  (k, l) the other two axes, c (1/(m/s^2))

The seed kept product terms in its final models and blamed 'interference of tightly mounted
cables'. The Q-Flex sensor model has no such term: the triad's readings are each a function of
their own axis' a_S, so the exact inverse model holds no product of two readings and the truth is
c = 0 (stage "sensor": a parameter the sensor model would carry). ``inject`` applies a c of its own
to a signal (tests and a lab that wants one).

Diagnosis (static positions): the product of the other two axes' indicated specific forces.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from imurig.sensors.effects._qflex import AXES
from imurig.sensors.effects.base import Candidate, Effect, Param, PositionView


@dataclass
class CrossCoupling(Effect):
    """c (3,) 1/(m/s^2): axis j's coupling to the product of the other two."""

    coupling_per_m_s2: np.ndarray = field(default_factory=lambda: np.zeros(3))

    name: ClassVar[str] = "cross_coupling"
    stage: ClassVar[str] = "sensor"
    physics: ClassVar[str] = "cross-coupling of the other two axes (a product term a_k a_l)"
    seed_section: ClassVar[str] = "4.3.5, Tables 4.5-4.6"
    seed_says: ClassVar[str] = ("cross terms like a_x a_z 'can be caused by interference of tightly mounted cables "
                                "that are unshielded'; a_y a_z for A_x and a_x a_z for A_y and A_z were kept")
    params: ClassVar[tuple] = (Param("c", "1/(m/s^2)", note="inverse-model coefficient of the other two "
                                                              "readings' product; 0 in the Q-Flex model"),)
    views: ClassVar[tuple] = ("positions",)
    order: ClassVar[int] = 50

    def __post_init__(self):
        self.coupling_per_m_s2 = np.broadcast_to(np.asarray(self.coupling_per_m_s2, float), (3,)).copy()

    def inject(self, a: np.ndarray, ctx=None, rng=None) -> np.ndarray:
        """a_j + c_j a_k a_l for a (n, 3) m/s^2."""
        a = np.asarray(a, float)
        prod = np.stack([a[:, 1] * a[:, 2], a[:, 0] * a[:, 2], a[:, 0] * a[:, 1]], axis=1)
        return a + self.coupling_per_m_s2 * prod

    def candidates(self, view: PositionView) -> list[Candidate]:
        o = [f"a{a}" for a in AXES if a != view.axis]
        r = view.readings
        return [Candidate(self.name, "cross-coupling of the other two axes (product term)", ("c",),
                          lambda _, o=o: r[o[0]] * r[o[1]])]

    def fitted(self, truth: Mapping, channel: str | None = None) -> dict[str, float]:
        """{c: 0}: the Q-Flex triad injects no product term (module doc)."""
        return {"c": 0.0}
