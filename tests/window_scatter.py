"""Shared test helper: the scatter of two recordings' channels about each window's mean agrees."""
from __future__ import annotations

import numpy as np


def pooled_window_sd(rec, name: str) -> tuple[float, int]:
    """The sd of channel ``name`` about each segment window's own mean, pooled over the windows, and the count."""
    x = np.concatenate([rec.channels[name][sl] - rec.channels[name][sl].mean() for sl in rec.segment_slices()])
    return float(x.std()), x.size


def assert_same_window_scatter(a, b, names) -> None:
    """Two independent realisations of the same noise: per channel the pooled sd agree within 4 standard
    errors (the sd of a pooled sd is ~ sd / sqrt(2 N); of the ratio of two independent ones sqrt(2 / (2 N)))."""
    for k in names:
        (s1, n), (s2, _) = pooled_window_sd(a, k), pooled_window_sd(b, k)
        assert abs(s1 / s2 - 1) < 4 * np.sqrt(2 / (2 * n)), (k, s1, s2)
