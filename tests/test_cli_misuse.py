"""Misuse on the command line ends in one clear message and exit 2: no traceback, nothing written."""
from __future__ import annotations

import json

import pytest

from imurig.cli.main import main


@pytest.mark.parametrize("argv, says", [
    (["campaign", "tilt-table", "--theta", "nan,30,60"], "finite numbers"),
    (["campaign", "tilt-table", "--start-time", "notadate"], "ISO 8601"),
    (["campaign", "magnetometer", "--start-time", "2005-13-45"], "ISO 8601"),
])
def test_bad_options_are_refused_by_the_parser(argv, says, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv + ["--out", str(tmp_path / "o")])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and not (tmp_path / "o").exists()


def _one_position_csv(tmp_path):
    import independent_lab as lab

    src = lab.write_recording(tmp_path / "full.csv", "tilt_table", None, 3)
    lines = src.read_text().splitlines()
    keep = lines[:3] + [ln for ln in lines[3:] if all(float(v) == 0 for v in ln.split(",")[1:3])][:500]
    dst = tmp_path / "one.csv"
    dst.write_text("\n".join(keep) + "\n")
    return dst


@pytest.mark.parametrize("command", ["calibrate", "diagnose"])
def test_a_single_position_is_refused_with_what_to_add(command, tmp_path, capsys):
    one = _one_position_csv(tmp_path)
    assert main([command, str(one), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert str(one) in err and "Add positions" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("content, says", [
    ("[]", "not an imurig accelerometer calibration"),
    ('{"kind": "imurig.accelerometer_inverse_model", "axes": {"x": {"terms": ["1", "ax"], "coef": [1]}}}', "axes"),
    ('{"kind": "imurig.accelerometer_inverse_model", "axes": {"x": {"terms": ["1", "aw"], "coef": [1, 2]}, '
     '"y": {"terms": ["1"], "coef": [1]}, "z": {"terms": ["1"], "coef": [1]}}}', "unknown inputs"),
    ("\x00\x01", "cannot read calibration"),
])
def test_apply_checks_the_calibration_file(content, says, tmp_path, capsys):
    cal = tmp_path / "cal.json"
    cal.write_text(content)
    rec = tmp_path / "r.csv"
    rec.write_text("# rig: tilt_table\n# site: delft\ntime_s,acc_x_V\n0,0\n0.01,0\n")
    assert main(["apply", str(cal), str(rec), "--out", str(tmp_path / "out.h5")]) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and not (tmp_path / "out.h5").exists()


def test_every_option_has_help_and_no_empty_default():
    """Help text on every option of every command, no '(default: None)', and every command listed in
    the top-level help."""
    import argparse

    from imurig.cli.main import build_parser

    bad = set()

    def walk(p, path):
        for act in p._actions:
            if isinstance(act, argparse._SubParsersAction):
                for name, sp in act.choices.items():
                    walk(sp, path + [name])
            elif not isinstance(act, argparse._HelpAction) and not (act.help or "").strip():
                bad.add((" ".join(path), "/".join(act.option_strings) or act.dest))
        if "(default: None)" in p.format_help():
            bad.add((" ".join(path), "(default: None)"))

    for camp in ("tilt-table", "turn-table", "thermal", "magnetometer"):
        walk(build_parser(["campaign", camp]), ["imurig"])
    top = build_parser([])
    walk(top, ["imurig"])
    assert not bad, sorted(bad)
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    text = top.format_help().split("positional arguments")[0]
    assert [c for c in sub.choices if f"imurig {c}" not in text] == []


def test_a_flight_too_short_to_score_is_refused(tmp_path, capsys):
    assert main(["flight", "--duration", "60", "--seed", "7", "--out", str(tmp_path / "f")]) == 2
    err = capsys.readouterr().err
    assert "settling" in err and "at least 65 s" in err and not (tmp_path / "f").exists()


def test_a_thermal_profile_with_too_few_steps_is_refused_before_simulating(tmp_path, capsys):
    # -10..10 C in 10 C steps, one cycle: 5 steps for the cubic bias with its hysteresis gap (5 terms)
    argv = ["campaign", "thermal", "--low", "-10", "--high", "10", "--cycles", "1", "--out", str(tmp_path / "t")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "5 temperature steps" in err and "--cycles" in err and "Traceback" not in err
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("command", ["diagnose", "info", "calibrate"])
@pytest.mark.parametrize("what", ["missing.csv", "missing.h5", "folder.csv"])
def test_a_missing_file_or_a_folder_is_named_not_a_traceback(command, what, tmp_path, capsys):
    """A path that is not a readable file: one line that names it, exit 2, no report folder."""
    path = tmp_path / what
    if what.startswith("folder"):
        path.mkdir()
    argv = [command, str(path)] + ([] if command == "info" else ["--out", str(tmp_path / "o")])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert str(path) in err and err.startswith("imurig: error:") and "Traceback" not in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("sep, says", [(";", "separated by ';'"), ("\t", "separated by a tab")])
@pytest.mark.parametrize("command", ["diagnose", "info"])
def test_a_file_separated_by_other_than_commas_says_so(sep, says, command, tmp_path, capsys):
    """European spreadsheets save ';'-separated 'CSV', loggers tab-separated: the message names the separator."""
    path = tmp_path / "lab.csv"
    path.write_text("# rig: tilt_table\n" + sep.join(["time_s", "acc_x_V", "theta_deg", "phi_deg"]) + "\n"
                    + "".join(sep.join([f"{i * 1e-3:.3f}", "0,1", "0", "0"]) + "\n" for i in range(5)))
    argv = [command, str(path)] + ([] if command == "info" else ["--out", str(tmp_path / "o")])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert says in err and "Traceback" not in err and not (tmp_path / "o").exists()


def test_a_schedule_too_long_for_the_machine_is_refused_before_it_runs(tmp_path, capsys):
    """A dwell of 1e6 s (2.4e11 samples): one message with the sizes and what to shorten, at once, no folder
    (it used to be killed by the system for memory after half a minute)."""
    import time

    t = time.perf_counter()
    assert main(["campaign", "tilt-table", "--dwell", "1e6", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "2.4e+11 samples" in err and "shorten --dwell" in err and "Traceback" not in err
    assert not (tmp_path / "o").exists() and time.perf_counter() - t < 20


def test_a_recording_larger_than_the_free_disk_is_refused_before_writing(tmp_path):
    from imurig.kernel.errors import ConfigError
    from imurig.kernel.outputs import check_disk

    check_disk(tmp_path / "new" / "r.h5", 1e6, "the recording", "shorten it", free_bytes=2e6)
    with pytest.raises(ConfigError, match=r"about 0.003 GB on disk, but only 0.002 GB are free there; shorten it"):
        check_disk(tmp_path / "new" / "r.h5", 3e6, "the recording", "shorten it", free_bytes=2e6)
    assert not (tmp_path / "new").exists()


def _console(*args, **kw):
    """The installed ``imurig`` command's entry point (imurig.cli.run) in a fresh process."""
    import subprocess
    import sys

    code = "import sys; from imurig.cli import run; sys.argv = ['imurig', *sys.argv[1:]]; run()"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120,
                          env=_buffered_env(), **kw)


def _buffered_env() -> dict:
    """This environment with the standard streams block-buffered into a pipe, as a user's shell has them."""
    import os

    return {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}


def test_console_command_ends_with_its_exit_code_and_all_its_output():
    """The console entry ends the process without the interpreter's teardown when nothing is left running:
    what the command printed to a pipe arrives whole, and the exit code is the command's (0, and 2 with a
    message for a misuse)."""
    from imurig.cli.main import main as in_process

    ok = _console("concealed", "list")
    assert ok.returncode == 0, ok.stderr
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert in_process(["concealed", "list"]) == 0
    assert ok.stdout == buf.getvalue() and ok.stdout.strip()
    bad = _console("info", "no-such-recording.h5")
    assert bad.returncode == 2
    assert bad.stderr.startswith("imurig: error:") and "Traceback" not in bad.stderr


def test_console_entry_flushes_what_the_command_printed_before_it_ends():
    """imurig.cli.run ends the process itself: output still in the pipe's buffer is written first, and the
    exit code is the command's; with a thread still running it exits as usual (the thread is joined)."""
    import subprocess
    import sys

    prog = ("import sys, threading, time; import imurig.cli as c\n"
            "def fake():\n"
            "    print('x' * 100)\n"
            "    if sys.argv[1] == 'thread':\n"
            "        threading.Thread(target=lambda: (time.sleep(0.3), print('joined', flush=True))).start()\n"
            "    return 3\n"
            "c.main = fake\n"
            "c.run()\n")
    for mode, tail in (("plain", ""), ("thread", "joined\n")):
        r = subprocess.run([sys.executable, "-c", prog, mode], capture_output=True, text=True, timeout=60,
                           env=_buffered_env())
        assert r.returncode == 3 and r.stdout == "x" * 100 + "\n" + tail, (mode, r)
