"""Node keys reach `ropemon decode` and `ropemon monitor` from a key file, the environment or a
node.json, never from the command line (where every user of the computer can read them)."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from host_rig import KEYS, frame_set
from ropemon.cli import main
from ropemon.station.protocol import keys_from_options, read_key_file

SECRET = "5e" * 16


def _key_file(tmp_path, text: str, mode: int = 0o600):
    p = tmp_path / "node.key"
    p.write_text(text)
    p.chmod(mode)
    return p


@pytest.mark.parametrize("command", [["decode", "-"], ["monitor", "--port", "loop://"]])
def test_a_key_on_the_command_line_is_refused_saying_what_to_use(command, capsys):
    with pytest.raises(SystemExit) as e:
        main([*command, "--key", f"1:{SECRET}"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "argument --key: refused: a key on the command line can be read by every user" in err
    assert "--key-file NODE:PATH" in err and "ROPEMON_KEY_<NODE>=HEX" in err and "--config node.json" in err
    assert SECRET not in err  # the refusal does not repeat the key


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660])
def test_a_key_file_others_may_read_is_refused_with_the_reason(tmp_path, mode):
    p = _key_file(tmp_path, SECRET, mode)
    with pytest.raises(ValueError) as e:
        read_key_file(f"3:{p}")
    msg = str(e.value)
    assert f"has mode {mode:04o}, so group or others may read (or change) the key" in msg
    assert f"chmod 600 {p}" in msg and SECRET not in msg
    p.chmod(0o600)
    assert read_key_file(f"3:{p}") == (3, bytes.fromhex(SECRET))
    p.chmod(0o400)
    assert read_key_file(f"3:{p}") == (3, bytes.fromhex(SECRET))


def test_key_file_faults_are_named(tmp_path):
    p = _key_file(tmp_path, "00" * 8)
    for spec, message in ((f"{p}", "expected NODE:PATH"), (f"x:{p}", "node 'x' is not an integer"),
                          (f"256:{p}", "node 256 outside 0..255"), (f"1:{p}", "the key is 8 bytes, expected 16..32"),
                          (f"1:{tmp_path / 'absent.key'}", "cannot read")):
        with pytest.raises(ValueError, match=message):
            read_key_file(spec)


def test_keys_from_the_environment(tmp_path):
    env = {"ROPEMON_KEY_2": KEYS[2].hex(), "PATH": "/bin", "ROPEMON_KEYS": "not one"}
    assert keys_from_options([], [], env=env) == {2: KEYS[2]}
    p = _key_file(tmp_path, KEYS[1].hex())
    assert keys_from_options([f"1:{p}"], [], env=env) == {1: KEYS[1], 2: KEYS[2]}
    with pytest.raises(ValueError, match="node 1: --key-file 1:.* and ROPEMON_KEY_1 give different keys"):
        keys_from_options([f"1:{p}"], [], env={"ROPEMON_KEY_1": KEYS[2].hex()})
    with pytest.raises(ValueError, match="ROPEMON_KEY_1: the key is not hex") as e:
        keys_from_options([], [], env={"ROPEMON_KEY_1": "zz" + SECRET})
    assert SECRET not in str(e.value)
    with pytest.raises(ValueError, match="ROPEMON_KEY_pithead: node 'pithead' is not an integer"):
        keys_from_options([], [], env={"ROPEMON_KEY_pithead": SECRET})


def test_decode_takes_keys_from_a_key_file_or_the_environment(tmp_path):
    frames = frame_set(3, 10, True)
    data = b"".join(w for _, w in frames)
    files = []
    for node, key in KEYS.items():
        p = tmp_path / f"{node}.key"
        p.write_text(key.hex() + "\n")
        p.chmod(0o600)
        files.append(f"--key-file={node}:{p}")
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("ROPEMON_KEY_")}
    for args, extra_env in ((files, {}), ([], {f"ROPEMON_KEY_{n}": k.hex() for n, k in KEYS.items()})):
        r = subprocess.run([sys.executable, "-m", "ropemon.cli", "decode", "-", *args], input=data,
                           capture_output=True, timeout=60, env={**env, **extra_env})
        assert r.returncode == 0, r.stderr
        rows = [json.loads(x) for x in r.stdout.splitlines()]
        assert len(rows) == 10 and all(row["authenticated"] is True for row in rows)
