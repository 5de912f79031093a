"""One command line: the same flag means the same thing in every command, and the edges behave.

``--rate`` is a sample rate (Hz) everywhere and ``--speed`` paces replays; list options
take ``a,b`` and ``a b``; ``--version``; a reader closing the pipe early or Ctrl-C during
start-up ends a command without a traceback; ``eval`` shows progress.
"""
from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

from streamfix import __version__
from streamfix.cli import build_parser, main

from test_e2e_harness import PROJECT_ROOT, child_env, free_port


def _cli(*args: str, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "streamfix", *args], capture_output=True, text=True,
                          timeout=timeout, env=child_env(), cwd=str(PROJECT_ROOT), **kw)


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"streamfix {__version__}"


@pytest.mark.parametrize("command", [["serve"], ["replay", "take.csv"], ["view", "take.csv"]])
def test_rate_on_a_replaying_command_says_use_speed(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--rate", "2"])
    assert exc.value.code == 2
    assert "use --speed 2" in capsys.readouterr().err


def test_speed_is_checked_where_it_paces(capsys):
    assert main(["serve", "--speed", "-1", "--out", f"tcp://127.0.0.1:{free_port()}"]) == 2
    assert "--speed must be >= 0" in capsys.readouterr().err


def test_rate_is_a_sample_rate_where_it_exists():
    parser = build_parser()
    for argv in (["eval", "x.bvh", "--rate", "30"], ["report", "x.csv", "-o", "r.html", "--rate", "30"]):
        assert parser.parse_args(argv).rate == 30.0
    for command in ("eval", "report"):
        help_text = parser._subparsers._group_actions[0].choices[command].format_help()
        assert "HZ" in help_text


@pytest.mark.parametrize("flag, values, expected", [
    ("--levels", ["10,20"], [10.0, 20.0]),
    ("--levels", ["10", "20"], [10.0, 20.0]),
    ("--methods", ["input,savgol"], ["input", "savgol"]),
    ("--methods", ["input", "savgol"], ["input", "savgol"]),
])
def test_list_options_take_commas_or_spaces(flag, values, expected):
    args = build_parser().parse_args(["eval", "x.bvh", flag, *values])
    assert getattr(args, flag[2:]) == expected


def test_list_options_repeat_and_name_a_bad_item(capsys):
    parser = build_parser()
    for command in (["tap", "tcp://127.0.0.1:5556"], ["record", "tcp://127.0.0.1:5556", "o.sfrec"]):
        for topics in (["live,clean"], ["live", "clean"]):
            assert parser.parse_args([*command, "--topic", *topics]).topic == ["live", "clean"]
    assert parser.parse_args(["eval", "x.bvh", "--methods", "a,b", "--methods", "c"]).methods == ["a", "b", "c"]
    assert parser.parse_args(["report", "x.csv", "-o", "r.html", "--joints", "HandLeft", "HandRight"]).joints == [
        "HandLeft", "HandRight"]
    with pytest.raises(SystemExit):
        parser.parse_args(["eval", "x.bvh", "--levels", "10,ten"])
    assert "--levels: 'ten' is not a valid float" in capsys.readouterr().err


def test_levels_help_says_what_a_level_is_per_protocol():
    help_text = " ".join(build_parser()._subparsers._group_actions[0].choices["eval"].format_help().split())
    for words in ("noise = % of coordinates", "gaps = % of joint-frames", "occlusion = % of joints",
                  "long-gaps = gap length in frames", "blackout = % of each window"):
        assert words in help_text


def test_levels_on_a_protocol_without_levels_is_an_error(shared_data, capsys):
    take = str(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    assert main(["eval", take, "--protocol", "kinect", "--levels", "10"]) == 2
    assert "--levels does not apply to protocol kinect" in capsys.readouterr().err


def test_lookahead_is_seconds_or_frames_in_serve_and_clean(shared_data, tmp_path, capsys):
    """The same --lookahead syntax in both; clean's old bare frame count now reads as seconds
    and is refused as longer than the window, not silently used."""
    take = str(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    assert main(["clean", take, str(tmp_path / "a.csv"), "--lookahead", "30"]) == 2
    assert "lookahead must be in 0..window-1" in capsys.readouterr().err
    assert main(["clean", take, str(tmp_path / "b.csv"), "--lookahead", "12f"]) == 0
    assert "lookahead 12 frames" in capsys.readouterr().out
    assert main(["clean", take, str(tmp_path / "c.csv"), "--lookahead", "0.4s"]) == 0
    assert "lookahead 12 frames" in capsys.readouterr().out  # 0.4 s at the take's 30.3 Hz


def test_tap_stops_after_duration_like_record_and_view():
    t0 = time.monotonic()
    proc = _cli("tap", f"tcp://127.0.0.1:{free_port()}", "--duration", "0.5", "--count", "1")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr  # nothing arrived before the duration
    assert time.monotonic() - t0 < 20


def test_eval_json_into_a_closed_pipe_ends_quietly(shared_data):
    take = str(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    proc = subprocess.Popen([sys.executable, "-m", "streamfix", "eval", take, "--json", "--methods", "input"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=child_env(), cwd=str(PROJECT_ROOT))
    proc.stdout.close()  # the reader goes away before the first byte (as `| head -c 0` would)
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, err
    assert "Traceback" not in err and "BrokenPipe" not in err


def test_eval_progress_line_on_request(shared_data):
    take = str(shared_data / "kinect_v2" / "Ges01_wavehand.csv")
    proc = _cli("eval", take, "--methods", "input", "--progress", timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "streamfix eval: protocol kinect on " in proc.stderr and " done" in proc.stderr
    quiet = _cli("eval", take, "--methods", "input", timeout=120)  # stderr is a pipe: no progress line
    assert "protocol kinect on" not in quiet.stderr


def test_ctrl_c_during_serve_start_up_is_one_line_not_a_traceback():
    """Ctrl-C while ``serve`` loads its service and engine. The signal goes once the child is
    in streamfix's own code (``-X importtime`` reports the first module under ``streamfix.cli``
    imported: ``main`` is building the command line, and the service, numpy and zmq are still
    to load): a fixed delay raced the interpreter's own start-up on a loaded machine, where a
    Ctrl-C is Python's traceback, not streamfix's."""
    proc = subprocess.Popen([sys.executable, "-X", "importtime", "-m", "streamfix", "serve",
                             "--out", f"tcp://127.0.0.1:{free_port()}"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=child_env(),
                            cwd=str(PROJECT_ROOT))
    lines: list[str] = []
    in_main = threading.Event()

    def read() -> None:
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("import time:") and line.rsplit("|", 1)[-1].strip().startswith("streamfix.cli."):
                in_main.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert in_main.wait(60), "".join(lines)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(10)
    err = "".join(line for line in lines if not line.startswith("import time:"))
    # 130, or killed by SIGINT (-2): CPython re-raises SIGINT at exit when a native module's
    # init was interrupted, even though streamfix caught the KeyboardInterrupt
    assert proc.returncode in (130, -signal.SIGINT, 0), err
    assert "Traceback" not in err, err


def test_serve_demo_says_how_to_watch_and_stop_and_that_the_replay_ended(tmp_path):
    demo = sorted((PROJECT_ROOT / "replay_data").glob("*.csv"))[0]
    proc = _cli("serve", "--source", str(demo), "--speed", "0", "--engine", "passthrough",
                "--out", f"tcp://127.0.0.1:{free_port()}", "--status-interval", "0", timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "streamfix tap tcp://127.0.0.1:" in proc.stderr and "stop it: Ctrl-C" in proc.stderr
    assert "input ended" in proc.stderr
