"""The readers refuse every damaged file with the project's own error, naming the file: hypothesis
draws a valid recording, damages it in one of the ways real files break (a missing or wrong-typed
part, bad JSON, a dangling or external link, a group swapped for a dataset, text where numbers go,
a scalar or 2-D channel, NaN time, no samples, truncated or random bytes), and ``load`` must either
give a recording that validates or raise :class:`ImurigError` with the file's name, never anything
else. IMURIG_FUZZ_EXAMPLES (default 150) sets the cases per reader; the slow run takes 10,000."""
from __future__ import annotations

import os

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from imurig.kernel.errors import ImurigError
from imurig.kernel.files import load
from imurig.kernel.h5stream import h5_info, h5_to_csv
from imurig.kernel.recording import Recording, save_h5

N_EXAMPLES = int(os.environ.get("IMURIG_FUZZ_EXAMPLES", "150"))
FUZZ = settings(max_examples=N_EXAMPLES, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _recording(n: int, rng: np.random.Generator) -> Recording:
    t = np.arange(n) / 100.0
    return Recording(time_s=t, channels={f"acc_{a}": rng.normal(size=n) for a in "xyz"},
                     units={f"acc_{a}": "V" for a in "xyz"},
                     segments={"start_s": np.array([0.0]), "stop_s": np.array([t[-1]]), "label": np.array(["a"])},
                     meta={"rig": "tilt_table"})


def _damage(f: h5py.File, how: str, x: float) -> None:
    if how == "no_meta":
        del f.attrs["meta"]
    elif how == "meta_not_text":
        f.attrs["meta"] = np.arange(3)
    elif how == "meta_bad_json":
        f.attrs["meta"] = '{"rig": tilt'
    elif how == "meta_list":
        f.attrs["meta"] = "[1, 2]"
    elif how == "truth_bad_json":
        f.attrs["truth"] = "{"
    elif how == "no_format":
        del f.attrs["format"]
    elif how == "no_time":
        del f["time_s"]
    elif how == "time_2d":
        del f["time_s"]
        f["time_s"] = np.zeros((4, 2))
    elif how == "time_nan":
        t = f["time_s"][()]
        del f["time_s"]
        t[int(x * (t.size - 1))] = np.nan
        f["time_s"] = t
    elif how == "time_empty":
        del f["time_s"]
        f["time_s"] = np.zeros(0)
    elif how == "time_text":
        del f["time_s"]
        f["time_s"] = np.array([b"a", b"b"])
    elif how == "channels_dataset":
        del f["channels"]
        f["channels"] = np.arange(4.0)
    elif how == "channel_group":
        del f["channels/acc_x"]
        f.create_group("channels/acc_x")
    elif how == "channel_scalar":
        del f["channels/acc_x"]
        f["channels/acc_x"] = 1.0
    elif how == "channel_2d":
        del f["channels/acc_x"]
        f["channels/acc_x"] = np.zeros((3, 3))
    elif how == "channel_text":
        del f["channels/acc_x"]
        f["channels/acc_x"] = np.array([b"x"] * 3)
    elif how == "channel_short":
        n = f["channels/acc_y"].shape[0]
        del f["channels/acc_y"]
        f["channels/acc_y"] = np.zeros(max(0, int(x * n) - 1))
    elif how == "channel_bad_quantum":
        f["channels/acc_z"].attrs["quantum"] = "lots"
    elif how == "dangling_link":
        del f["channels/acc_x"]
        f["channels/acc_x"] = h5py.SoftLink("/nowhere")
    elif how == "external_link":
        del f["segments"]
        f["segments"] = h5py.ExternalLink("missing.h5", "/segments")
    elif how == "no_segments":
        del f["segments"]
    elif how == "segment_nan":
        s = f["segments/start_s"][()]
        del f["segments/start_s"]
        f["segments/start_s"] = s * np.nan
    elif how == "segment_rows":
        del f["segments/stop_s"]
        f["segments/stop_s"] = np.zeros(3)
    elif how == "compound":
        del f["channels/acc_x"]
        f["channels/acc_x"] = np.zeros(3, dtype=[("a", "f8"), ("b", "i4")])


HOW = ("no_meta", "meta_not_text", "meta_bad_json", "meta_list", "truth_bad_json", "no_format", "no_time", "time_2d",
       "time_nan", "time_empty", "time_text", "channels_dataset", "channel_group", "channel_scalar", "channel_2d",
       "channel_text", "channel_short", "channel_bad_quantum", "dangling_link", "external_link", "no_segments",
       "segment_nan", "segment_rows", "compound", "truncate", "random_bytes", "none")


def _check(path):
    try:
        rec = load(path)
    except ImurigError as e:
        assert path.name in str(e), str(e)
        out = "refused"
    else:
        rec.validate()
        out = "accepted"
    if path.suffix == ".h5":   # the streaming readers of `info` and `convert` never crash either
        for stream in (lambda: h5_info(path), lambda: h5_to_csv(path, path.with_suffix(".csv"), overwrite=True)):
            try:
                stream()
            except ImurigError as e:
                assert path.name in str(e), str(e)
    return out


CASE = dict(how=st.sampled_from(HOW), n=st.integers(2, 40), x=st.floats(0.0, 1.0), seed=st.integers(0, 2**16))


def _one_h5_case(tmp_path_factory, how, n, x, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path_factory.mktemp("h5") / "rec.h5"
    save_h5(_recording(n, rng), path)
    if how == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: int(x * len(data))])
    elif how == "random_bytes":
        path.write_bytes(rng.bytes(int(1 + x * 4000)))
    elif how != "none":
        with h5py.File(path, "r+") as f:
            _damage(f, how, x)
    out = _check(path)
    if how == "none":
        assert out == "accepted"
    if how in ("no_meta", "meta_bad_json", "time_nan", "time_empty", "channel_scalar", "dangling_link",
               "external_link", "random_bytes"):
        assert out == "refused", how


@FUZZ
@given(**CASE)
def test_hdf5_reader_never_crashes(tmp_path_factory, how, n, x, seed):
    _one_h5_case(tmp_path_factory, how, n, x, seed)


@pytest.mark.slow
@settings(FUZZ, max_examples=10_000)
@given(**CASE)
def test_hdf5_reader_never_crashes_10000(tmp_path_factory, how, n, x, seed):
    """The same property at 10,000 cases (the slow run's figure for the issue)."""
    _one_h5_case(tmp_path_factory, how, n, x, seed)


# ---------------------------------------------------------------------------------------------- lab CSV
GOOD_CSV = """# rig: tilt_table
# site: delft
time_s,theta_deg,phi_deg,acc_x_V,acc_y_V,acc_z_V,temp_box_degC
"""


def _good_rows(n: int, rng) -> list[str]:
    """A tilt table at six positions, outputs 1 V per g (the other lab's convention: f/g =
    (-cos phi sin theta, sin phi sin theta, cos theta))."""
    pos = [(0, 0), (90, 0), (90, 90), (90, 180), (90, 270), (180, 0)]
    rows = []
    for k in range(n):
        th, ph = pos[min(5, k * 6 // n)]
        t, p = np.radians(th), np.radians(ph)
        f = (-np.cos(p) * np.sin(t), np.sin(p) * np.sin(t), np.cos(t))
        rows.append(f"{k / 100:.2f},{th},{ph}," + ",".join(f"{v + 1e-3 * rng.normal():.5f}" for v in f) + ",25.0")
    return rows


CSV_HOW = ("none", "bom", "latin1", "random_bytes", "setpoints_number", "setpoints_nested", "setpoints_unknown",
           "no_header", "header_only", "dup_header", "no_time", "text_value", "short_row", "nan_time", "time_back",
           "unknown_site", "bad_unit", "truncate", "empty", "meta_garbage", "segment_col_text", "run_nan",
           "theta_rad_in_degrees", "swap_xy")


def _csv_text(how: str, n: int, x: float, rng) -> bytes:
    head, rows = GOOD_CSV, _good_rows(n, rng)
    if how == "setpoints_number":
        head = "# setpoints: 5\n" + head
    elif how == "setpoints_nested":
        head = '# setpoints: [["theta"], ["phi"]]\n' + head
    elif how == "setpoints_unknown":
        head = '# setpoints: ["psi"]\n' + head
    elif how == "no_header":
        head = "# rig: tilt_table\n# site: delft\n"
    elif how == "header_only":
        rows = []
    elif how == "dup_header":
        head = head.replace("phi_deg", "theta_deg")
    elif how == "no_time":
        head = head.replace("time_s", "t_s")
    elif how == "text_value":
        rows[int(x * (n - 1))] = rows[int(x * (n - 1))].replace("25.0", "warm")
    elif how == "short_row":
        rows[int(x * (n - 1))] = ",".join(rows[int(x * (n - 1))].split(",")[:3])
    elif how == "nan_time":
        r = rows[int(x * (n - 1))].split(",")
        rows[int(x * (n - 1))] = ",".join(["nan"] + r[1:])
    elif how == "time_back":
        rows = rows[::-1]
    elif how == "unknown_site":
        head = head.replace("delft", "atlantis")
    elif how == "bad_unit":
        head = head.replace("acc_x_V", "acc_x_furlongs")
    elif how == "meta_garbage":
        head = "# : : :\n# key with spaces: 1\n# json: {[\n" + head
    elif how == "segment_col_text":
        head = head.replace("temp_box_degC", "segment")
        rows = [r.rsplit(",", 1)[0] + ",a" for r in rows]
    elif how == "run_nan":
        head = '# setpoints: ["theta", "phi"]\n' + head.replace("temp_box_degC", "run")
        rows = [r.rsplit(",", 1)[0] + ",nan" for r in rows]
    elif how == "theta_rad_in_degrees":
        head = head.replace("theta_deg", "theta_rad")
    elif how == "swap_xy":
        head = head.replace("acc_x_V,acc_y_V", "acc_y_V,acc_x_V")
    text = (head + "\n".join(rows) + "\n").encode("utf-8")
    if how == "bom":
        text = b"\xef\xbb\xbf" + text
    elif how == "latin1":
        text = text.replace(b"delft", "d\xe9lft".encode("latin-1"))
    elif how == "random_bytes":
        text = rng.bytes(int(1 + x * 2000))
    elif how == "truncate":
        text = text[: int(x * len(text))]
    elif how == "empty":
        text = b""
    return text


def _one_csv_case(tmp_path_factory, how, n, x, seed):
    rng = np.random.default_rng(seed)
    path = tmp_path_factory.mktemp("csv") / "lab.csv"
    path.write_bytes(_csv_text(how, n, x, rng))
    out = _check(path)
    if how in ("none", "bom"):
        assert out == "accepted", how
    if how in ("latin1", "setpoints_number", "setpoints_nested", "no_header", "dup_header", "no_time", "text_value",
               "unknown_site", "empty", "swap_xy"):
        assert out == "refused", how


@FUZZ
@given(how=st.sampled_from(CSV_HOW), n=st.integers(600, 1200), x=st.floats(0.0, 1.0), seed=st.integers(0, 2**16))
def test_lab_csv_reader_never_crashes(tmp_path_factory, how, n, x, seed):
    _one_csv_case(tmp_path_factory, how, n, x, seed)


@pytest.mark.slow
@settings(FUZZ, max_examples=10_000)
@given(how=st.sampled_from(CSV_HOW), n=st.integers(600, 1200), x=st.floats(0.0, 1.0), seed=st.integers(0, 2**16))
def test_lab_csv_reader_never_crashes_10000(tmp_path_factory, how, n, x, seed):
    _one_csv_case(tmp_path_factory, how, n, x, seed)


# ---------------------------------------------------------------------------------------------- scoring files
def test_scoring_readers_refuse_damaged_files(tmp_path):
    from imurig.scoring.files import read_estimates
    from imurig.scoring.score import TruthSet
    from imurig.scoring.interface import EstimatesError

    cases = {"bin.json": b"\x89PNG\r\n\x1a\n\x00\xff", "num.json": b"5", "list.json": b"[1, 2]",
             "bad.json": b'[{"name": "b", "value": "x", "std_error": 1, "unit": "V"}]', "bin.csv": b"\xff\xfe\x00a"}
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(EstimatesError) as e:
            read_estimates(tmp_path / name)
        assert name in str(e.value)
    for d in ([], {"format": "imurig-truth"}, {"format": "x"}):
        with pytest.raises(EstimatesError):
            TruthSet.from_dict(d)
    (tmp_path / "truth.json").write_bytes(b"\xff\x00")
    with pytest.raises(EstimatesError, match="truth.json"):
        TruthSet.load(tmp_path / "truth.json")
