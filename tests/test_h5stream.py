"""``imurig info`` and ``imurig convert`` (HDF5 -> CSV) in row chunks: the same summary and the same
CSV bytes as the full load, and a peak memory that does not grow with the file."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from imurig.cli.main import main
from imurig.kernel import csvstream, h5stream
from imurig.kernel.errors import RecordingError
from imurig.kernel.files import load
from imurig.kernel.labcsv import write_csv
from imurig.kernel.recording import Recording, save_h5

Q = 10.0 / 2**16           # one LSB of a 16-bit converter on +-5 V (channels stored as int16 codes)


def synthetic(n: int, seed: int = 0) -> Recording:
    """Two runs (a remount gap between them) of ``n`` samples at 1 kHz; segments with runs that
    leave moving rows between them; four quantised voltage channels, a set-point in rad and a
    counter's events; every value of the channels an exact multiple of the LSB."""
    rng = np.random.default_rng(seed)
    half = n // 2
    t = np.concatenate([np.arange(half), np.arange(n - half) + half + 600_000]) * 1e-3
    ch = {f"acc_{a}": np.round(rng.normal(0.5, 0.2, n) / Q) * Q for a in "xyz"}
    ch["temp_box"] = np.round((2.9 + 1e-3 * np.sin(t)) / Q) * Q
    ch["theta"] = np.repeat(np.radians(np.arange(n // 1000 + 1) * 7.0 % 360), 1000)[:n]
    starts = t[np.arange(100, n - 1000, 1000)]
    segs = {"start_s": starts, "stop_s": starts + 0.6, "run": (starts > t[half - 1]).astype(int),
            "theta": np.radians(np.arange(starts.size) * 7.0 % 360)}
    return Recording(time_s=t, channels=ch, units={**{k: "V" for k in ch}, "theta": "rad"}, segments=segs,
                     segment_units={"start_s": "s", "stop_s": "s", "run": "1", "theta": "rad"},
                     meta={"rig": "tilt_table", "site": {"latitude_deg": 52.0}, "setpoints": ["theta"]},
                     truth={"seed": seed}, truth_signals={"f_C_x": rng.normal(size=n)},
                     truth_units={"f_C_x": "m/s^2"}, channel_quantum={k: Q for k in ch if k != "theta"},
                     events={"pulse_hp6700": t[::997] + 3e-4, "pulse_true": t[::1000]})


def test_stream_equals_full_load_across_chunk_edges(tmp_path, monkeypatch, capsys):
    p = save_h5(synthetic(20_000), tmp_path / "r.h5")
    rec = load(p)
    write_csv(rec, tmp_path / "full.csv")
    monkeypatch.setattr(h5stream, "CHUNK_ROWS", 777)          # many chunk edges, inside segments and gaps
    assert main(["convert", str(p), str(tmp_path / "stream.csv")]) == 0
    assert (tmp_path / "stream.csv").read_bytes() == (tmp_path / "full.csv").read_bytes()
    capsys.readouterr()
    assert main(["info", str(p)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info == {"samples": rec.n, "duration_s": float(rec.time_s[-1] - rec.time_s[0]),
                    "sample_rate_hz": rec.sample_rate_hz, "blocks": 2, "channels": rec.units,
                    "segments": rec.n_segments, "segment_columns": sorted(rec.segments),
                    "meta_keys": sorted(rec.meta), "has_truth": True, "inferred": {}, "import_warnings": []}


@pytest.mark.parametrize("structure", ["segment column", "set-points line"])
def test_csv_to_h5_in_blocks_equals_the_whole_file_import(tmp_path, monkeypatch, structure):
    rec = synthetic(20_000)
    write_csv(rec, tmp_path / "r.csv")
    if structure == "set-points line":           # no segment/run columns: segments from set-point changes
        head, _, body = (tmp_path / "r.csv").read_text().partition("time_s,")
        rows = [r.split(",") for r in ("time_s," + body).splitlines()]
        keep = [i for i, h in enumerate(rows[0]) if h not in ("segment", "run")]
        (tmp_path / "r.csv").write_text(head + "\n".join(",".join(r[i] for i in keep) for r in rows) + "\n")
    full = load(save_h5(load(tmp_path / "r.csv"), tmp_path / "full.h5"))
    monkeypatch.setattr(csvstream, "BLOCK_ROWS", 777)        # block edges inside segments
    assert main(["convert", str(tmp_path / "r.csv"), str(tmp_path / "blocks.h5")]) == 0
    back = load(tmp_path / "blocks.h5")
    assert back.meta == full.meta and back.units == full.units and back.segment_units == full.segment_units
    for got, want in ((back.channels, full.channels), (back.segments, full.segments), (back.events, full.events),
                      ({"t": back.time_s}, {"t": full.time_s})):
        assert sorted(got) == sorted(want)
        for k in want:
            assert got[k].dtype == want[k].dtype and np.array_equal(got[k], want[k]), k
    assert full.n_segments == (19 if structure == "segment column" else 20)


def _by_hand(path, rec: Recording) -> None:
    """``rec``'s time and channels (float64) as save_h5 lays them out, without its checks."""
    import h5py

    with h5py.File(path, "w") as f:
        f.attrs["format"], f.attrs["meta"] = "imurig-recording", "{}"
        f.create_dataset("time_s", data=rec.time_s)
        g = f.create_group("channels")
        for k, v in rec.channels.items():
            g.create_dataset(k, data=v).attrs["unit"] = "V"
        f.create_group("segments")


@pytest.mark.parametrize("damage", ["nan", "clock"])
def test_stream_refuses_what_loading_refuses(tmp_path, monkeypatch, damage):
    """A NaN in a channel, a clock that steps back at a chunk edge: the same refusal as loading."""
    rec = synthetic(3000)
    if damage == "nan":
        rec.channels["acc_y"][2500] = np.nan
    else:
        rec.time_s[2000] = rec.time_s[1999]
    p = tmp_path / "bad.h5"
    _by_hand(p, rec)
    with pytest.raises(RecordingError) as full:
        load(p)
    monkeypatch.setattr(h5stream, "CHUNK_ROWS", 1000)
    for call in (lambda: h5stream.h5_info(p), lambda: h5stream.h5_to_csv(p, tmp_path / "x.csv")):
        with pytest.raises(RecordingError) as streamed:
            call()
        assert str(streamed.value) == str(full.value)
    assert not (tmp_path / "x.csv").exists()


# the peak of this process' own memory (VmHWM, Linux): ru_maxrss would also hold the RSS its parent
# (the test runner) had when it forked
PEAK = """
import re, sys
from imurig.cli.main import main
def peak_mb():
    with open("/proc/self/status") as fh:
        return int(re.search(r"VmHWM:\\s+(\\d+) kB", fh.read())[1]) / 1024
base = peak_mb()
assert main(["info", sys.argv[1]]) == 0
info = peak_mb()
assert main(["convert", sys.argv[1], sys.argv[2]]) == 0
convert = peak_mb()
assert main(["convert", sys.argv[2], sys.argv[2] + ".h5"]) == 0
print(base, info, convert, peak_mb())
"""


def _peaks(path, out) -> np.ndarray:
    r = subprocess.run([sys.executable, "-c", PEAK, str(path), str(out)], capture_output=True, text=True,
                       check=True)
    return np.array([float(v) for v in r.stdout.split("\n")[-2].split()])


def test_info_and_convert_memory_does_not_grow_with_the_file(tmp_path):
    """Peak memory (VmHWM) of info, convert to CSV, then that CSV back to HDF5, on 100 k and 700 k
    rows (several chunks each). Growth measured for the 600 k extra rows: streamed 0.2-0.6 MB for
    each step (CSV -> HDF5 below the CSV step's peak); the whole-file paths before this 42 MB (info)
    and 184 MB (convert), and 88 MB for CSV -> HDF5 on 300 k extra rows. Bound: 8 MB, two chunks'
    worth of the file's seven float64 columns (2 x 64 Ki x 7 x 8 B = 7.3 MB), a fifth of the full
    load's growth for info."""
    small, large = (save_h5(synthetic(n, seed=1), tmp_path / f"r{n}.h5") for n in (100_000, 700_000))
    a = _peaks(small, tmp_path / "a.csv")
    b = _peaks(large, tmp_path / "b.csv")
    growth = (b - b[0]) - (a - a[0])            # info, convert to CSV, convert back to HDF5
    assert np.all(growth[1:] < 8.0), (a, b)


@pytest.mark.parametrize("deflater", ["isal", "zlib"])
@pytest.mark.parametrize("n", [1 << 16, 70_001, 100])
def test_chunk_deflate_is_a_zlib_stream_hdf5_inflates(tmp_path, n, deflater, monkeypatch):
    """An 8-byte signal's chunk and an int16 channel's (imurig.kernel.h5write._deflate): runs (a signal at rest),
    a moving part (busy low mantissa bytes), zeros and a short last chunk; zlib inflates each chunk to the
    shuffled bytes, and HDF5's shuffle + deflate filters read the chunks back to the values, bit for bit, with
    ISA-L's deflater and with zlib's (where isal is missing)."""
    import zlib

    import h5py

    from imurig.kernel import h5write

    if deflater == "zlib":
        monkeypatch.setattr(h5write, "isal_zlib", None)
    else:
        assert h5write.isal_zlib is not None, "isal (a dependency) is not installed"
    rng = np.random.default_rng(3)
    rows = min(h5write.CHUNK_ROWS, n)
    x = np.repeat(rng.normal(size=n // 500 + 1), 500)[:n]
    moving = slice(n // 5, n // 2)
    x[moving] = np.cumsum(rng.normal(size=x[moving].size)) * 1e-3
    x[-n // 10:] = 0.0
    codes = np.round(x * 3000 + rng.normal(0, 3, n)).astype(np.int16)
    with h5py.File(tmp_path / "c.h5", "w") as f:
        for name, values in (("x", x), ("codes", codes)):
            ds = f.create_dataset(name, shape=(n,), dtype=values.dtype, chunks=(rows,), compression="gzip",
                                  compression_opts=h5write.GZIP_LEVEL, shuffle=True)
            for c in range(0, n, rows):
                piece = values[c:c + rows]
                z = h5write._deflate(piece, rows, h5write.STRATEGY)
                padded = np.concatenate((piece, np.zeros(rows - piece.size, values.dtype)))
                assert zlib.decompress(z) == padded.view(np.uint8).reshape(-1, values.itemsize).T.tobytes()
                ds.id.write_direct_chunk((c,), z)
    with h5py.File(tmp_path / "c.h5") as f:
        assert np.array_equal(f["x"][:].view(np.uint64), x.view(np.uint64))
        assert np.array_equal(f["codes"][:], codes)
