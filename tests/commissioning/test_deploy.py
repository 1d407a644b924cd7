"""`ropemon deploy`: arch detection, the host-side build, config checks, and atomic deploys
end to end with the real mpremote against a virtual node (MicroPython unix port on a pty).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ropemon.commission import deploy as D
from ropemon.firmware import FIRMWARE_DIR
from ropemon.lab.virtualnode import VirtualNode, micropython_command


# --- arch detection and compatibility

def test_decode_mpy_of_the_unix_port():
    r = subprocess.run([micropython_command(), "-c", "import sys; print(sys.implementation._mpy)"],
                       capture_output=True, text=True, timeout=10)
    assert D.decode_mpy(int(r.stdout)) == (6, 3, "x64")


@pytest.mark.parametrize("arch", ["armv6m", "armv7emsp", "xtensawin", "rv32imc"])
def test_decode_mpy_of_mcu_ports(arch):
    sys_mpy = 6 | (3 << 8) | (D.MPY_ARCHES.index(arch) << 10)
    assert D.decode_mpy(sys_mpy) == (6, 3, arch)


def test_decode_mpy_without_native_emitter_and_unknown_arch():
    assert D.decode_mpy(6 | (3 << 8)) == (6, 3, None)
    with pytest.raises(D.DeployError, match="unknown native arch 13"):
        D.decode_mpy(6 | (13 << 10))


def _info(mpy_version=6, sub=3, arch="armv7emsp"):
    return D.NodeInfo(version="1.29.0", platform="rp2", mpy_version=mpy_version, mpy_sub=sub,
                      arch=arch, cwd="/", free_bytes=None, journal=None)


def test_choose_arch_follows_the_node():
    assert D.choose_arch(_info(), None, as_py=False) == "armv7emsp"
    assert D.choose_arch(_info(), None, as_py=True) is None


def test_a_wrong_arch_or_mpy_version_is_refused():
    with pytest.raises(D.DeployError, match="--arch xtensawin given, but the node's native arch is armv7emsp"):
        D.choose_arch(_info(), "xtensawin", as_py=False)
    with pytest.raises(D.DeployError, match=r"loads \.mpy v5\.2.*use --py"):
        D.choose_arch(_info(mpy_version=5, sub=2), None, as_py=False)
    # A node too old to report _mpy needs the arch from the user.
    with pytest.raises(D.DeployError, match="give --arch"):
        D.choose_arch(_info(mpy_version=None, sub=None, arch=None), None, as_py=False)


# --- the host-side build

def _tree(root: Path, version: str, pad_bytes: int = 0) -> Path:
    """A firmware tree: this repo's firmware/ with FIRMWARE_VERSION set to `version`.

    `pad_bytes` adds a module of that size so a copy takes many raw-paste windows.
    """
    shutil.copytree(FIRMWARE_DIR, root, ignore=shutil.ignore_patterns("__pycache__"))
    init = root / "ropenode" / "__init__.py"
    text = init.read_text()
    assert 'FIRMWARE_VERSION = "' in text
    init.write_text(text.replace(f'FIRMWARE_VERSION = "{_repo_version()}"', f'FIRMWARE_VERSION = "{version}"'))
    if pad_bytes:
        (root / "ropenode" / "padding.py").write_text(
            "TABLE = (\n" + "".join(f"    {i},\n" for i in range(pad_bytes // 10)) + ")\n")
    return root


def _repo_version() -> str:
    for line in (FIRMWARE_DIR / "ropenode" / "__init__.py").read_text().splitlines():
        if line.startswith("FIRMWARE_VERSION"):
            return line.split('"')[1]
    raise AssertionError("no FIRMWARE_VERSION in firmware/ropenode/__init__.py")


def test_build_compiles_the_package_and_keeps_top_level_files_as_source(tmp_path):
    fw = _tree(tmp_path / "fw", "9.9.9")
    out = tmp_path / "out"
    out.mkdir()
    hashes = D.build(fw, out, "armv6m", as_py=False, config=None)
    assert "main.py" in hashes and (out / "main.py").read_bytes() == (fw / "main.py").read_bytes()
    assert "ropenode/layout.mpy" in hashes and "ropenode/layout.py" not in hashes
    assert "manifest.py" not in hashes  # a freezing manifest is for building images, not for the node
    assert (out / "ropenode" / "layout.mpy").read_bytes()[:2] == b"M\x06"
    for rel, h in hashes.items():
        assert hashlib.sha256((out / rel).read_bytes()).hexdigest() == h


def test_build_with_py_copies_sources(tmp_path):
    fw = _tree(tmp_path / "fw", "9.9.9")
    out = tmp_path / "out"
    out.mkdir()
    hashes = D.build(fw, out, None, as_py=True, config=None)
    assert "ropenode/layout.py" in hashes and not any(p.endswith(".mpy") for p in hashes)


def test_build_names_the_file_mpy_cross_rejects(tmp_path):
    fw = _tree(tmp_path / "fw", "9.9.9")
    (fw / "ropenode" / "broken.py").write_text("def f(:\n")
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(D.DeployError, match=r"mpy-cross failed on ropenode/broken\.py"):
        D.build(fw, out, "armv6m", as_py=False, config=None)


def test_a_tree_without_main_py_is_refused(tmp_path):
    fw = _tree(tmp_path / "fw", "9.9.9")
    (fw / "main.py").unlink()
    with pytest.raises(D.DeployError, match="no main.py"):
        D.firmware_sources(fw)


# --- config checks (before anything touches the node)

SITE = FIRMWARE_DIR.parent / "scenarios" / "paper-site.toml"


@pytest.fixture(scope="module")
def node_json(tmp_path_factory) -> Path:
    """node.json of the paper's hoist, made by `ropemon config` as a user would: with the
    node's own key in a key file (the demo key of the example site is refused by deploy)."""
    from ropemon.cli import main
    site = own_key_site(tmp_path_factory.mktemp("config"))
    out = site.parent / "node.json"
    assert main(["config", str(site), "--out", str(out)]) == 0
    return out


def own_key_site(d: Path) -> Path:
    """The paper's site copied to `d` with a random key of its own in `node-1.key` (mode 0600)."""
    for name in ("paper-friction.json", "paper-compliance.json"):
        shutil.copy(SITE.parent / name, d / name)
    (d / "node-1.key").write_text(os.urandom(16).hex() + "\n")
    (d / "node-1.key").chmod(0o600)
    text = SITE.read_text()
    assert text.count('key_hex = "00112233445566778899aabbccddeeff"') == 1
    site = d / "paper-site.toml"
    site.write_text(text.replace('key_hex = "00112233445566778899aabbccddeeff"', 'key_file = "node-1.key"'))
    return site


def _edited(tmp_path: Path, node_json: Path, edit) -> Path:
    doc = json.loads(node_json.read_text())
    edit(doc)
    p = tmp_path / "edited.json"
    p.write_text(json.dumps(doc))
    return p


def test_the_generated_config_passes(node_json):
    assert D.check_config(node_json)["crc"] == json.loads(node_json.read_text())["crc"]


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.pop("crc"), "field 'crc'"),
    (lambda d: d.update(schema=2), "field 'schema': unknown schema 2"),
    (lambda d: d["node"].update(ropes=3), "field 'crc': mismatch"),  # edited after `ropemon config`
    (lambda d: d.update(node=[]), "field 'node'"),
])
def test_bad_configs_are_refused_naming_the_field(tmp_path, node_json, edit, message):
    with pytest.raises(D.DeployError, match=message):
        D.check_config(_edited(tmp_path, node_json, edit))


def test_a_bad_config_is_refused_before_connecting(tmp_path, node_json, capsys):
    from ropemon.cli import main
    bad = _edited(tmp_path, node_json, lambda d: d["node"].update(ropes=3))
    assert main(["deploy", "--port", "/dev/ropemon-no-such-port", "--config", str(bad)]) == 1
    err = capsys.readouterr().err
    assert "field 'crc'" in err and "port" not in err


def test_a_config_that_is_not_json_is_refused(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{"schema": 1,')
    with pytest.raises(D.DeployError, match="not JSON"):
        D.check_config(p)


# --- end to end against the virtual node

def _live_hashes(root: Path) -> dict[str, str]:
    """sha256 of every file the node would boot from (staging and journal excluded)."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if p.is_file() and rel.parts[0] not in (D.STAGED_DIR, D.PREV_DIR, D.JOURNAL):
            out[rel.as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _boot(root: Path, code: str) -> str:
    """Start a fresh micropython in the node directory (a reboot) and run `code`."""
    r = subprocess.run([micropython_command(), "-c", code], cwd=root, capture_output=True, text=True,
                       timeout=20, env={"MICROPYPATH": ""})
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def _version_on(root: Path) -> str:
    return _boot(root, "import ropenode; print(ropenode.FIRMWARE_VERSION)").strip()


def test_deploy_cli_end_to_end(tmp_path, node_json):
    fw = _tree(tmp_path / "fw", "1.0.0-test")
    cfg = node_json
    with VirtualNode(tmp_path / "node") as node:
        # Exactly as on a board: no --resume, so every mpremote run soft-resets the node first.
        r = subprocess.run([sys.executable, "-m", "ropemon.cli", "deploy", "--port", node.port,
                            "--firmware", str(fw), "--config", str(cfg)],
                           capture_output=True, text=True, timeout=60)
        resets = node.soft_resets
    assert r.returncode == 0, r.stdout + r.stderr
    assert resets == 4  # probe, stage, swap, report (and the hard reset: none, the unix port has no machine.reset)
    doc = json.loads(cfg.read_text())
    crc, node_id = doc["crc"], doc["node"]["node_id"]
    assert "arch x64" in r.stdout
    assert f"firmware 1.0.0-test, config CRC {crc} (0x{crc:04x}), node id {node_id}" in r.stdout
    root = tmp_path / "node"
    # the node gets its part of the config: the same node section and CRC, no physical section
    on_node = json.loads((root / "node.json").read_text())
    assert on_node == {key: doc[key] for key in ("schema", "node", "crc")} and "physical" in doc
    assert (root / "ropenode" / "__init__.mpy").exists() and not (root / "ropenode" / "__init__.py").exists()
    assert not (root / D.STAGED_DIR).exists() and not (root / D.PREV_DIR).exists()
    assert not (root / D.JOURNAL).exists()
    assert _version_on(root) == "1.0.0-test"


def test_a_config_the_deployed_firmware_refuses_fails_the_deploy(tmp_path, node_json):
    """The read-back uses the node's own config loader: a refusal there is an error, not a success."""
    fw = _tree(tmp_path / "fw", "1.0.0")
    with open(fw / "ropenode" / "config.py", "a") as f:
        f.write('\n\ndef parse(doc):\n    raise ConfigError("node.ropes", "refused by this test build")\n')
    with VirtualNode(tmp_path / "node") as node:
        r = subprocess.run([sys.executable, "-m", "ropemon.cli", "deploy", "--port", node.port, "--resume",
                            "--firmware", str(fw), "--config", str(node_json)],
                           capture_output=True, text=True, timeout=60)
    assert r.returncode == 1, r.stdout + r.stderr
    assert "firmware 1.0.0, node.json REFUSED by the node: node.ropes: refused by this test build" in r.stdout


def _hard_reset_seen(root: Path, wait_s: float) -> bool:
    """Whether the stand-in machine.reset ran on the node (it is sent with --no-follow)."""
    import time

    end = time.monotonic() + wait_s
    while not (root / "hard-reset").exists() and time.monotonic() < end:
        time.sleep(0.1)
    return (root / "hard-reset").exists()


def test_a_clean_deploy_ends_with_a_hard_reset(tmp_path, node_json):
    """So the node leaves the maintenance window its first Ctrl-C opened (docs/hardware.md,
    step 12) and samples with the new firmware at once; not with --no-reset, nor when the
    read-back fails (exit code 1). The unix port has no machine.reset: a machine.py in the
    node's directory stands in for it (a board's never returns)."""
    fw = _tree(tmp_path / "fw", "1.0.0")
    bad = _tree(tmp_path / "bad", "1.0.1")
    with open(bad / "ropenode" / "config.py", "a") as f:
        f.write('\n\ndef parse(doc):\n    raise ConfigError("node.ropes", "refused by this test build")\n')
    root = tmp_path / "node"
    root.mkdir()
    (root / "machine.py").write_text("def reset():\n    open('hard-reset', 'w').close()\n")
    with VirtualNode(root) as node:
        r = subprocess.run([sys.executable, "-m", "ropemon.cli", "deploy", "--port", node.port, "--resume",
                            "--firmware", str(fw), "--config", str(node_json)],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0, r.stdout + r.stderr
        assert r.stdout.splitlines()[-1] == "resetting the node: it boots the new firmware and samples"
        assert _hard_reset_seen(root, 5)
        (root / "hard-reset").unlink()
        report = D.deploy(node.port, fw, config=node_json, resume=True, log=lambda s: None, reset=False)
        assert report["can_reset"] and not report["reset"]
        report = D.deploy(node.port, bad, config=node_json, resume=True, log=lambda s: None)
        assert "config_error" in report and not report["reset"]
        assert not _hard_reset_seen(root, 1)


def test_redeploy_replaces_the_whole_package(tmp_path):
    """Going from .py to .mpy must not leave a .py that would shadow the new .mpy."""
    v1, v2 = _tree(tmp_path / "v1", "1.0.0"), _tree(tmp_path / "v2", "2.0.0")
    (v1 / "ropenode" / "old_only.py").write_text("X = 1\n")
    with VirtualNode(tmp_path / "node") as node:
        D.deploy(node.port, v1, as_py=True, resume=True, log=lambda s: None)
        assert (node.root / "ropenode" / "__init__.py").exists()
        report = D.deploy(node.port, v2, resume=True, log=lambda s: None)
    assert report["firmware_version"] == "2.0.0"
    root = tmp_path / "node"
    assert sorted(p.name for p in (root / "ropenode").iterdir()) == sorted(
        p.stem + ".mpy" for p in (v2 / "ropenode").glob("*.py"))
    assert _version_on(root) == "2.0.0"


def test_port_not_found_and_node_not_answering(tmp_path):
    fw = _tree(tmp_path / "fw", "1.0.0")
    with pytest.raises(D.DeployError, match="port /dev/ropemon-no-such-port not found"):
        D.deploy("/dev/ropemon-no-such-port", fw, resume=True, log=lambda s: None)
    # A port with nothing behind it: a pty whose other end never answers.
    import os
    import pty
    master, slave = pty.openpty()
    try:
        with pytest.raises(D.DeployError, match="did not answer within 1 s"):
            D.deploy(os.ttyname(slave), fw, resume=True, timeout_s=1, log=lambda s: None)
    finally:
        os.close(master)
        os.close(slave)


def _deploy_counting_bytes(node: VirtualNode, fw: Path) -> tuple[int, int]:
    """Deploy; return the host->node byte counts where staging starts and where it is verified."""
    marks: dict[str, int] = {}

    def log(line: str) -> None:
        if line.startswith("built "):
            marks["staging"] = node.host_to_node_bytes
        elif "staged files match" in line:
            marks["verified"] = node.host_to_node_bytes

    D.deploy(node.port, fw, resume=True, log=log)
    return marks["staging"], marks["verified"]


@pytest.fixture(scope="module")
def two_versions(tmp_path_factory, node_json):
    """Firmware v1 and v2 (v2 padded by ~12 kB), a node directory with v1 and node.json
    deployed, and where in the host->node byte stream of a v1 -> v2 deploy the staging
    starts and is verified (from an undisturbed run on a copy of that node)."""
    base = tmp_path_factory.mktemp("versions")
    v1 = _tree(base / "v1", "1.0.0")
    v2 = _tree(base / "v2", "2.0.0", pad_bytes=12000)
    with VirtualNode(base / "v1-node") as node:
        D.deploy(node.port, v1, config=node_json, resume=True, log=lambda s: None)
    shutil.copytree(base / "v1-node", base / "scratch")
    with VirtualNode(base / "scratch") as node:
        start, end = _deploy_counting_bytes(node, v2)
    assert end - start > 12000
    return v1, v2, base / "v1-node", start, end


@pytest.mark.parametrize("where", [0.02, 0.5, 0.98])
def test_a_transfer_broken_midway_leaves_the_previous_firmware(tmp_path, two_versions, node_json, where):
    """Power cut near the start, in the middle and near the end of staging (prepare, copy, hash)."""
    v1, v2, v1_node, stage_start, stage_end = two_versions
    root = tmp_path / "node"
    shutil.copytree(v1_node, root)
    before = _live_hashes(root)

    with VirtualNode(root) as node:
        node.break_after(int(stage_start + where * (stage_end - stage_start)))
        with pytest.raises(D.DeployError, match="the live firmware on the node is unchanged"):
            D.deploy(node.port, v2, resume=True, log=lambda s: None)
        assert not node.running()
    if where == 0.5:  # the cut came mid-copy: part of v2 is on the node, beside v1
        staged = [p for p in (root / D.STAGED_DIR).rglob("*") if p.is_file()]
        assert 0 < len(staged) < len(list(v2.rglob("*.py")))

    # Reboot: the node boots v1 exactly as before, and it still frames the sensor stream.
    assert _live_hashes(root) == before
    assert _version_on(root) == "1.0.0"
    _run_sim_on_node(root, tmp_path, json.loads(node_json.read_text()), [9.0e6] * 4)

    if where != 0.5:
        return
    # The next deploy clears the half-staged leftovers and completes.
    with VirtualNode(root) as node:
        report = D.deploy(node.port, v2, resume=True, log=lambda s: None)
    assert report["firmware_version"] == "2.0.0"
    assert not (root / D.STAGED_DIR).exists()
    assert _version_on(root) == "2.0.0"


def test_a_hash_mismatch_stops_before_the_swap(tmp_path, monkeypatch):
    v1, v2 = _tree(tmp_path / "v1", "1.0.0"), _tree(tmp_path / "v2", "2.0.0")
    root = tmp_path / "node"
    real_build = D.build

    def build_with_a_wrong_hash(*a, **k):
        hashes = real_build(*a, **k)
        hashes["ropenode/layout.mpy"] = "0" * 64  # what a corrupted transfer looks like from here
        return hashes

    with VirtualNode(root) as node:
        D.deploy(node.port, v1, resume=True, log=lambda s: None)
        before = _live_hashes(root)
        monkeypatch.setattr(D, "build", build_with_a_wrong_hash)
        with pytest.raises(D.DeployError, match=r"hash mismatch on the node for ropenode/layout\.mpy; "
                                                r"the live firmware on the node is unchanged"):
            D.deploy(node.port, v2, resume=True, log=lambda s: None)
    assert _live_hashes(root) == before
    assert _version_on(root) == "1.0.0"


def test_too_little_flash_is_refused_before_staging(tmp_path, monkeypatch):
    import dataclasses
    fw = _tree(tmp_path / "fw", "1.0.0")
    real_probe = D.probe
    monkeypatch.setattr(D, "probe", lambda mp: dataclasses.replace(real_probe(mp), free_bytes=1000))
    with VirtualNode(tmp_path / "node") as node:
        with pytest.raises(D.DeployError, match=r"the node has 1000 bytes free, the new files need \d+; "
                                                r"the live firmware on the node is unchanged"):
            D.deploy(node.port, fw, resume=True, log=lambda s: None)
    assert list((tmp_path / "node").iterdir()) == []


# --- a swap cut by a power loss: completed at the next boot by main.py (deployswap)

class _PowerCut(Exception):
    """The node lost power: no further filesystem operation happens."""


class _CuttingOs:
    """os for deployswap under CPython that loses power before its `cut_at`-th change."""

    def __init__(self, cut_at: int) -> None:
        self.left = cut_at
        self.changes = 0

    def _change(self, f, *a):
        if self.left == 0:
            raise _PowerCut
        self.left -= 1
        self.changes += 1
        return f(*a)

    def rename(self, a, b):
        return self._change(os.rename, a, b)

    def remove(self, p):
        return self._change(os.remove, p)

    def rmdir(self, p):
        return self._change(os.rmdir, p)

    def mkdir(self, p):
        return self._change(os.mkdir, p)

    stat = staticmethod(os.stat)

    @staticmethod
    def ilistdir(p):
        return [(e.name,) for e in os.scandir(p)]


def _swap_cut(root: Path, names: list[str], cut_at: int, monkeypatch) -> int:
    """Run the node's own swap (deployswap.swap) in `root`, cut before change `cut_at`;
    return the number of changes made."""
    fake = _CuttingOs(cut_at)
    with monkeypatch.context() as m:
        m.chdir(root)
        m.setattr(D.deployswap, "os", fake)
        try:
            D.deployswap.swap(names)
        except _PowerCut:
            pass
    return fake.changes


def _boot_main(root: Path) -> str:
    """Boot the node: run its main.py in the unix port until the board loop starts (here it
    stops at `machine.I2C`, absent from the unix port, which proves ropenode was imported)."""
    import select
    import time
    proc = subprocess.Popen([micropython_command(), "main.py"], cwd=root, env={"MICROPYPATH": ""},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    out = b""
    deadline = time.monotonic() + 20
    try:
        while b"can't import name I2C" not in out and time.monotonic() < deadline:
            if select.select([proc.stdout], [], [], 0.5)[0]:
                chunk = os.read(proc.stdout.fileno(), 4096)
                if not chunk:
                    break
                out += chunk
    finally:
        proc.kill()
        proc.wait()
    text = out.decode(errors="replace")
    assert "ropenode/hal_board.py" in text and "can't import name I2C" in text, text
    return text


@pytest.fixture(scope="module")
def swap_states(tmp_path_factory, two_versions):
    """A v1 node with v2 staged and verified (as deploy leaves it before the swap), the swap's
    item names, and the live files after an uncut swap."""
    v1, v2, v1_node, _, _ = two_versions
    base = tmp_path_factory.mktemp("swap")
    ready = base / "ready"
    shutil.copytree(v1_node, ready)
    hashes = D.build(v2, ready / D.STAGED_DIR, "x64", as_py=False, config=None)
    names = sorted({p.split("/")[0] for p in hashes})
    assert names == ["deployswap.mpy", "main.py", "ropenode"]
    done = base / "done"
    shutil.copytree(ready, done)
    mp = pytest.MonkeyPatch()
    try:
        changes = _swap_cut(done, names, 10**6, mp)
    finally:
        mp.undo()
    return ready, names, changes, _live_hashes(v1_node), _live_hashes(done)


def test_main_py_completes_a_swap_cut_at_any_step(tmp_path, swap_states, monkeypatch):
    ready, names, changes, v1_files, v2_files = swap_states
    assert v1_files != v2_files and changes >= 2 * len(names)
    for cut_at in range(changes + 1):
        root = tmp_path / f"cut{cut_at}"
        shutil.copytree(ready, root)
        assert _swap_cut(root, names, cut_at, monkeypatch) == cut_at
        journal = (root / D.JOURNAL).exists()
        out = _boot_main(root)
        if cut_at == 0:  # cut before the journal was in place: nothing was swapped
            assert not journal and _live_hashes(root) == v1_files
            continue
        assert _live_hashes(root) == v2_files, f"cut before change {cut_at}"
        assert not (root / D.JOURNAL).exists() and not (root / D.STAGED_DIR).exists()
        assert ("rolled forward" in out) == journal, (cut_at, out)
        assert _version_on(root) == "2.0.0"


def test_main_py_rolls_back_when_the_staged_set_is_incomplete(tmp_path, swap_states, monkeypatch):
    ready, names, changes, v1_files, _ = swap_states
    root = tmp_path / "node"
    shutil.copytree(ready, root)
    # The swap cut after deployswap.mpy and main.py, with `ropenode` half moved (live -> .prev/)...
    _swap_cut(root, names, 5, monkeypatch)
    assert not (root / "ropenode").exists() and (root / D.PREV_DIR / "ropenode").is_dir()
    assert (root / D.JOURNAL).exists()
    # ...and its staged copy lost: rolling forward would boot without a package.
    shutil.rmtree(root / D.STAGED_DIR / "ropenode")
    out = _boot_main(root)
    assert "rolled back" in out
    assert _live_hashes(root) == v1_files
    assert not any((root / d).exists() for d in (D.JOURNAL, D.STAGED_DIR, D.PREV_DIR))
    assert _version_on(root) == "1.0.0"


def test_an_unreadable_journal_rolls_back_what_prev_holds(tmp_path, swap_states, monkeypatch):
    ready, names, _, v1_files, _ = swap_states
    root = tmp_path / "node"
    shutil.copytree(ready, root)
    _swap_cut(root, names, 6, monkeypatch)  # ropenode swapped, journal still there
    (root / D.JOURNAL).write_text('["main.p')
    assert "rolled back" in _boot_main(root)
    assert _live_hashes(root) == v1_files
    assert _version_on(root) == "1.0.0"


def test_a_swap_cut_by_a_power_loss_is_finished_by_the_next_deploy(tmp_path, swap_states, two_versions,
                                                                    monkeypatch):
    """Without a boot in between (the node is reached over the REPL first), deploy finishes it."""
    ready, names, _, _, v2_files = swap_states
    v2 = two_versions[1]
    root = tmp_path / "node"
    shutil.copytree(ready, root)
    _swap_cut(root, names, 4, monkeypatch)
    assert (root / D.JOURNAL).exists()
    logged: list[str] = []
    with VirtualNode(root) as node:
        report = D.deploy(node.port, v2, resume=True, log=logged.append)
    assert any("cut during its swap" in line and "rolled forward" in line for line in logged), logged
    assert report["firmware_version"] == "2.0.0"
    assert not (root / D.JOURNAL).exists() and not (root / D.STAGED_DIR).exists()
    assert not (root / D.PREV_DIR).exists()
    assert _live_hashes(root) == v2_files
    assert _version_on(root) == "2.0.0"


# --- the deployed firmware runs: frames a short simulated stream

def _rsens(path: Path, phys: dict, pressures_pa: list[float], seconds: float) -> int:
    """A .rsens stream (docs/data-formats.md) of a cage at rest: constant pressures,
    pistons mid-stroke, battery healthy, no temperature input. Returns the sample count."""
    import struct
    n, hz = phys["ropes"], phys["sample_hz"]
    words = []
    for ch, p in zip(phys["pressure_channels"], pressures_pa):
        lo, hi = ch["range_Pa"]
        words.append(round(ch["counts_4mA"] + (p - lo) / (hi - lo) * (ch["counts_20mA"] - ch["counts_4mA"])))
    words += [(ch["counts_lo"] + ch["counts_hi"]) // 2 for ch in phys["displacement_channels"]]
    words += [round(2 * phys["battery_low_V"] / phys["battery_V_per_count"]), 0xFFFF, 0, 0]
    samples = int(seconds * hz)
    record = struct.pack(f"<{2 * n + 4}H", *words)
    path.write_bytes(struct.pack("<4sHHHH", b"RSNS", 1, n, hz, 0) + record * samples)
    return samples


def test_the_deployed_firmware_frames_a_simulated_stream(tmp_path, node_json):
    from ropemon.commission.replay import replay

    doc = json.loads(node_json.read_text())
    phys = doc["physical"]
    fw = _tree(tmp_path / "fw", _repo_version())  # this repo's firmware, as released
    root = tmp_path / "node"
    with VirtualNode(root) as node:
        report = D.deploy(node.port, fw, config=node_json, resume=True, log=lambda s: None)
    assert report["firmware_version"] == _repo_version() and report["node_id"] == doc["node"]["node_id"]
    assert [p.name for p in root.rglob("*.py")] == ["main.py"]

    pressures_pa = [8.0e6, 9.0e6, 10.0e6, 11.0e6]
    frames = _run_sim_on_node(root, tmp_path, doc, pressures_pa)
    # At rest (no piston motion, no flow) friction and pipe loss are zero: tension = p * A.
    for rope, p, area in zip(frames[-1].ropes, pressures_pa, phys["cylinder_area_m2"]):
        assert rope.mean_n == pytest.approx(p * area, rel=0.005)

    # The deployed .mpy build sends exactly the bytes of the source firmware in the repo.
    replay(tmp_path / "rest.rsens", tmp_path / "radio_src.bin", node_json)
    assert (tmp_path / "radio.bin").read_bytes() == (tmp_path / "radio_src.bin").read_bytes()


def _run_sim_on_node(root: Path, tmp_path: Path, doc: dict, pressures_pa: list[float]) -> list:
    """Boot the node's deployed firmware with the sim HAL on 2 s at rest; decode and check its frames."""
    from ropemon.station.decoder import StreamDecoder

    phys = doc["physical"]
    samples = _rsens(tmp_path / "rest.rsens", phys, pressures_pa, seconds=2.0)
    r = subprocess.run([micropython_command(), "-m", "ropenode.sim_main", "node.json",
                        str(tmp_path / "rest.rsens"), str(tmp_path / "radio.bin")],
                       cwd=root, env={"MICROPYPATH": ""}, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr
    n_frames = samples // (phys["sample_hz"] // phys["frame_hz"])
    assert r.stdout.split()[-4:] == ["samples", str(samples), "frames", str(n_frames)]

    dec = StreamDecoder(keys={doc["node"]["node_id"]: bytes(doc["node"]["key"])})
    frames = dec.feed((tmp_path / "radio.bin").read_bytes())
    dec.finish()
    c = dec.counts
    assert (c.frames_ok, c.crc_fail, c.malformed, c.mac_fail, c.bytes_discarded) == (n_frames, 0, 0, 0, 0)
    assert [f.seq for f in frames] == list(range(frames[0].seq, frames[0].seq + n_frames))
    assert all(f.node == doc["node"]["node_id"] and len(f.ropes) == phys["ropes"] for f in frames)
    # No temperature input is fitted; imbalance only where a rope is beyond +-10 % of the mean.
    mean = sum(pressures_pa) / len(pressures_pa)
    expected = {"temp_absent"} | ({"imbalance"} if any(abs(p / mean - 1) > 0.1 for p in pressures_pa) else set())
    assert all(set(f.status_flags) == expected for f in frames[1:]), [f.status_flags for f in frames]
    return frames


# --- the node-side helpers deploy sends over the REPL

def test_node_side_rmtree_is_deployswaps_and_empties_a_wide_tree(tmp_path):
    """deploy sends firmware/deployswap.py's `_kind`/`_rmtree` (the tree listed before it is
    deleted), no copy of its own; run under the real `micropython`, a wide nested tree goes."""
    assert D._NODE_TOOLS.count("def _rmtree(") == 1 and D._NODE_TOOLS.count("def _kind(") == 1
    assert "list(os.ilistdir(p))" in D._NODE_TOOLS
    tree = tmp_path / ".staged"
    for d in ("", "ropenode", "ropenode/sub"):
        (tree / d).mkdir(exist_ok=True)
        for i in range(40):
            (tree / d / f"f{i}.mpy").write_bytes(b"x" * i)
    script = D._NODE_TOOLS + "_rmtree('.staged')\n_rmtree('absent')\n_out([_kind('.staged'), _kind('absent')])\n"
    r = subprocess.run([micropython_command(), "-c", script], cwd=tmp_path, capture_output=True,
                       text=True, timeout=30)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "@@ropemon [null, null]"
    assert not tree.exists()


# --- a key published with ropemon

@pytest.mark.parametrize("config", ["shipped", "demo site"])
def test_a_config_with_a_published_key_is_refused_unless_allowed(tmp_path, capsys, config):
    """firmware/node.json's example key and the demo site's are in every copy of ropemon: a node
    deployed with one can be forged by anyone. Refused, loudly, before anything is copied."""
    from ropemon.cli import main
    if config == "shipped":
        cfg, which = FIRMWARE_DIR / "node.json", "the example key shipped in firmware/node.json"
    else:
        cfg, which = tmp_path / "node.json", "the demo key of scenarios/paper-site.toml"
        assert main(["config", str(SITE), "--out", str(cfg)]) == 0
        capsys.readouterr()
    assert main(["deploy", "--port", "/dev/ropemon-no-such-port", "--config", str(cfg)]) == 1
    err = capsys.readouterr().err
    assert f"carries {which}: it is published with ropemon, so anyone can forge frames of node 1" in err
    assert "REFUSED" in err and "--allow-example-key" in err and "port" not in err
    # allowed for a bench: warned on stderr, then the deploy goes on (to the missing port here)
    assert main(["deploy", "--port", "/dev/ropemon-no-such-port", "--config", str(cfg), "--allow-example-key"]) == 1
    err = capsys.readouterr().err
    assert f"WARNING: config {cfg} carries {which}" in err and "never on a hoist in service" in err
    assert "ropemon-no-such-port" in err


def test_the_published_keys_are_those_of_the_shipped_files():
    from ropemon.commission.nodejson import EXAMPLE_KEY, PUBLISHED_KEYS
    from ropemon.commission.site import load_site
    shipped = json.loads((FIRMWARE_DIR / "node.json").read_text())
    assert bytes(shipped["node"]["key"]) == EXAMPLE_KEY
    assert set(PUBLISHED_KEYS) == {EXAMPLE_KEY, load_site(SITE).key}


def test_a_config_edited_after_ropemon_config_is_refused(tmp_path, node_json):
    """The node never reads `physical`, but the host does: a file whose SHA-256 does not match is
    not deployed (node and station would read different things)."""
    bad = _edited(tmp_path, node_json, lambda d: d["physical"].update(imbalance_frac=0.2))
    with pytest.raises(D.DeployError, match=r"edited\.json: changed after `ropemon config` wrote it"):
        D.check_config(bad)
