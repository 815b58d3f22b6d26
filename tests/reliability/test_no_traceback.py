"""No Python traceback ever reaches the user: bad input or a lost device gives one line and the documented code.

Exit codes (docs/daemon.md): 1 runtime failure, 2 usage/configuration error,
3 connection failure.  Each case runs ``main([...])`` as the console script
does (fast), and a few run the real ``python -m mavahrs`` in subprocesses (the
interpreter's own top level included).  A test fails on any line containing
"Traceback", on more than one ERROR line, or on a wrong code.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from mavahrs.cli import main
from mavahrs.cli.common import EXIT_CONNECTION, EXIT_FAILURE, EXIT_USAGE

QUICK = ["--filter", "mahony", "--status-interval", "0", "--heartbeat-timeout", "0"]


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """Hostile inputs on disk."""
    rng = __import__("random").Random(5)
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(bytes(rng.randrange(256) for _ in range(5000)))
    garbage_toml = tmp_path / "garbage.toml"
    garbage_toml.write_bytes(bytes(rng.randrange(256) for _ in range(300)))
    bad_toml = tmp_path / "bad.toml"
    bad_toml.write_text("[daemon]\nmaster = 5\n[pipeline\n")
    typo_toml = tmp_path / "typo.toml"
    typo_toml.write_text('[pipeline]\nout_rate = 50\n')
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    text = tmp_path / "text.tlog"
    text.write_text("root:x:0:0:root:/root:/bin/bash\ndaemon:x:1:1:daemon:/usr/sbin:/usr/sbin/nologin\n")
    a_dir = tmp_path / "a_dir"
    a_dir.mkdir()
    key = tmp_path / "key.txt"
    key.write_text("x" * 64)
    key.chmod(0o600)
    return {"junk": junk, "garbage_toml": garbage_toml, "bad_toml": bad_toml, "typo_toml": typo_toml,
            "empty": empty, "text": text, "dir": a_dir, "missing": tmp_path / "missing.tlog", "key": key}


CASES = [
    # (id, argv with {placeholders}, code, words expected in the one error line)
    ("no-such-serial-device", ["run", *QUICK, "--master", "/dev/ttyNOSUCH9"], EXIT_CONNECTION, "no such device"),
    ("not-a-serial-device", ["run", *QUICK, "--master", "/etc/hostname"], EXIT_CONNECTION, "cannot open serial port"),
    ("garbage-config", ["run", *QUICK, "--config", "{garbage_toml}"], EXIT_USAGE, "not a text file"),
    ("broken-toml", ["run", *QUICK, "--config", "{bad_toml}"], EXIT_USAGE, "not valid TOML"),
    ("unknown-setting", ["run", *QUICK, "--config", "{typo_toml}"], EXIT_USAGE, "unknown setting"),
    ("config-is-a-directory", ["run", *QUICK, "--config", "{dir}"], EXIT_USAGE, "cannot read config file"),
    ("missing-config", ["run", *QUICK, "--config", "{missing}"], EXIT_USAGE, "not found"),
    ("unwritable-log", ["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--log", "{dir}/no/such/dir/x.tlog"],
     EXIT_USAGE, "cannot open log file"),
    ("log-is-a-directory", ["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--log", "{dir}"], EXIT_USAGE,
     "cannot open log file"),
    ("key-is-a-directory", ["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--signing-key", "{dir}"], EXIT_USAGE,
     "not a regular file"),
    ("bad-signing-link-id", ["run", *QUICK, "--signing-key", "{key}", "--signing-link-id", "300"], EXIT_USAGE,
     "signing_link_id"),
    ("replay-garbage-tlog", ["replay", "{junk}"], EXIT_FAILURE, "junk.tlog"),
    ("replay-empty-tlog", ["replay", "{empty}"], EXIT_FAILURE, "empty.tlog"),
    ("replay-missing-tlog", ["replay", "{missing}"], EXIT_FAILURE, "missing.tlog"),
    # a missing file and a directory: the same code (1, as documented in docs/reliability.md), said plainly
    ("replay-a-directory", ["replay", "{dir}"], EXIT_FAILURE, "a_dir is a directory: replay takes one log file"),
    ("tune-a-directory", ["tune", "{dir}"], EXIT_FAILURE, "a_dir is a directory: tune takes log files"),
    ("tune-missing-tlog", ["tune", "{missing}"], EXIT_FAILURE, "missing.tlog: no such file"),
    ("plot-a-directory", ["plot", "-o", "{dir}/p.png", "{dir}"], EXIT_FAILURE, "a_dir is a directory: plot takes"),
    ("calibrate-empty-tlog", ["calibrate-mag", "{empty}"], EXIT_FAILURE, "empty.tlog: the file is empty"),
    ("calibrate-text-file", ["calibrate-mag", "{text}"], EXIT_FAILURE, "text.tlog: no MAVLink messages in this file"),
    ("calibrate-a-directory", ["calibrate-mag", "{dir}"], EXIT_FAILURE, "a_dir is a directory: calibrate-mag takes"),
    ("unknown-master-prefix", ["run", *QUICK, "--master", "foo:bar:baz"], EXIT_USAGE,
     "'foo' is no known prefix; known prefixes: udpin, udp, udpout, udpbcast, tcp, tcpin"),
    ("evaluate-garbage-tlog", ["evaluate", "{junk}"], EXIT_FAILURE, "junk.tlog"),
    ("calibrate-garbage-tlog", ["calibrate-mag", "{junk}"], EXIT_FAILURE, "junk.tlog"),
]


def _argv(argv: list[str], files: dict[str, Path]) -> list[str]:
    return [a.format(**{k: str(v) for k, v in files.items()}) for a in argv]


def _check_output(err: str, code: int, expected: int, words: str) -> None:
    assert "Traceback" not in err, err
    errors = [line for line in err.splitlines() if " ERROR " in line or line.startswith("mavahrs")]
    assert code == expected, (code, err)
    assert len(errors) == 1 and words in errors[0], err
    assert "[Errno" not in err and "unknown input type ''" not in err, err  # Python's words, not ours


@pytest.mark.parametrize(("argv", "code", "words"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_is_one_line_and_the_documented_code(
    argv: list[str], code: int, words: str, files: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(_argv(argv, files))
    captured = capsys.readouterr()
    _check_output(captured.err + captured.out, rc, code, words)


def test_a_busy_port_is_one_line_and_exit_3(capsys: pytest.CaptureFixture[str]) -> None:
    for kind, sock_type in (("udpin", socket.SOCK_DGRAM), ("tcpin", socket.SOCK_STREAM)):
        holder = socket.socket(socket.AF_INET, sock_type)
        holder.bind(("127.0.0.1", 0))
        if sock_type == socket.SOCK_STREAM:
            holder.listen(1)
        try:
            rc = main(["run", *QUICK, "--master", f"{kind}:127.0.0.1:{holder.getsockname()[1]}"])
        finally:
            holder.close()
        _check_output(capsys.readouterr().err, rc, EXIT_CONNECTION, "already in use")


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their permissions")
def test_permission_denied_on_a_key_file_and_a_tlog(files: dict[str, Path], capsys: pytest.CaptureFixture[str]) -> None:
    files["key"].chmod(0o000)
    rc = main(["run", *QUICK, "--master", "udpin:127.0.0.1:0", "--signing-key", str(files["key"])])
    _check_output(capsys.readouterr().err, rc, EXIT_USAGE, "ermission denied")
    files["junk"].chmod(0o000)
    rc = main(["replay", str(files["junk"])])
    _check_output(capsys.readouterr().err, rc, EXIT_FAILURE, "junk.tlog")


@pytest.mark.slow
def test_the_real_entry_point_never_shows_a_traceback(rt, files: dict[str, Path]) -> None:
    """A few cases through ``python -m mavahrs`` (run concurrently: each pays the interpreter start-up)."""
    picked = [c for c in CASES if c[0] in ("no-such-serial-device", "garbage-config", "replay-garbage-tlog")]
    procs = [
        (c, subprocess.Popen([sys.executable, "-m", "mavahrs", *_argv(c[1], files)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=rt.env()))
        for c in picked
    ]
    for (_, _, code, words), p in procs:
        out, err = p.communicate(timeout=120)
        _check_output(err + out, p.returncode, code, words)
