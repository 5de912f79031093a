"""Argument errors name what the user typed: the flag and its valid range in the user's units,
or that a path is a directory, and exit 2 like argparse (not 1, not a traceback, and not
a message about an internal fraction, a resampler's dst_hz or a ZeroMQ endpoint)."""
from __future__ import annotations

import pytest

from streamfix.cli import main
from streamfix.io import read_motion

from test_e2e_harness import free_port

BVH = "cmu_bvh/131_01.bvh"  # ground truth: the noise protocol by default
CSV = "kinect_v2/Ges01_wavehand.csv"


def _parser_error(argv: list[str], capsys) -> str:
    """stderr of a command line the parser refuses (exit 2)."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("protocol, level, says", [
    ("noise", "-5", "% of coordinates given noise, 0 to 100"),
    ("noise", "150", "0 to 100"),
    ("gaps", "100", "% of joint-frames missing, 0 to less than 100"),
    ("long-gaps", "0", "gap length in frames, 1 or more"),
    ("blackout", "nan", "more than 0 up to 100"),
])
def test_eval_levels_out_of_range_names_the_flag_and_the_range(shared_data, capsys, protocol, level, says):
    argv = ["eval", str(shared_data / BVH), "--protocol", protocol, "--levels", "10", level, "--methods", "input"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"--levels {level} out of range for protocol {protocol}" in err and says in err
    assert "fraction" not in err


def test_eval_rate_must_be_positive(shared_data, capsys):
    for rate in ("0", "-30", "nan"):
        err = _parser_error(["eval", str(shared_data / BVH), "--rate", rate, "--methods", "input"], capsys)
        assert f"argument --rate: must be a number of Hz > 0, got {rate}" in err
        assert "dst_hz" not in err


def test_eval_directory_says_so_and_what_it_holds(shared_data, tmp_path, capsys):
    folder = shared_data / "kinect_v2"
    assert main(["eval", str(folder), "--methods", "input"]) == 2
    err = capsys.readouterr().err
    assert f"{folder} is a directory" in err and "only --protocol paired reads a directory" in err
    assert "5 motion file(s): Ges01_wavehand.csv" in err and f"{folder}/*.csv" in err
    assert "(none)" not in err
    assert main(["eval", str(tmp_path), "--protocol", "gaps"]) == 2
    assert "holds no motion files" in capsys.readouterr().err


def test_replay_directory_says_so(shared_data, capsys):
    folder = shared_data / "kinect_v2"
    assert main(["replay", str(folder), "--to", f"tcp://127.0.0.1:{free_port()}"]) == 2
    err = capsys.readouterr().err
    assert "kinect_v2: is a directory, not a motion file" in err and "(none)" not in err
    with pytest.raises(ValueError, match="is a directory"):
        read_motion(folder)


@pytest.mark.parametrize("flag, value, says", [
    ("--sndhwm", "-1", "must be an integer >= 0 (0 = no limit), got -1"),
    ("--linger-ms", "-5", "must be an integer >= -1 (-1 = wait forever), got -5"),
    ("--timeout", "nan", "must be a number of seconds > 0, got nan"),
])
def test_replay_socket_options_are_checked_by_the_parser(shared_data, capsys, flag, value, says):
    argv = ["replay", str(shared_data / CSV), "--to", f"tcp://127.0.0.1:{free_port()}", "--speed", "0", flag, value]
    err = _parser_error(argv, capsys)
    assert f"argument {flag}: {says}" in err and "cannot connect" not in err


def test_replay_config_value_out_of_range_names_the_key(shared_data, tmp_path, capsys):
    config = tmp_path / "streamfix.toml"
    config.write_text("[replay]\nsndhwm = -1\n")
    assert main(["replay", str(shared_data / CSV), "--config", str(config)]) == 2
    assert "[replay] sndhwm: -1 is not a valid integer >= 0" in capsys.readouterr().err


def test_clean_into_a_directory_says_it_is_one(shared_data, tmp_path, capsys):
    assert main(["clean", str(shared_data / CSV), str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path} is a directory" in err and "extension" not in err
