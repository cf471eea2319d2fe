"""A shared check of the streamed writers' HDF5 files (tests/test_tilt_stream.py, tests/test_turn_stream.py)."""
from __future__ import annotations

import h5py


def assert_same_header_and_layout(a: h5py.File, b: h5py.File) -> None:
    """The root attributes (format, version, meta, truth) equal, and every dataset at the same path with
    the same dtype and attributes."""
    for k in ("format", "version", "meta", "truth"):
        assert a.attrs[k] == b.attrs[k], k

    def layout(f):
        out = {}
        f.visititems(lambda n, o: out.update({n: (o.dtype.str, sorted(o.attrs.items()))})
                     if isinstance(o, h5py.Dataset) else None)
        return out
    assert layout(a) == layout(b)
