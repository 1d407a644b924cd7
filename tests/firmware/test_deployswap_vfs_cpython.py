"""deployswap on a board's filesystems (FAT and littlefs), cut by a power loss at every step.

tests/firmware/vfs_powercut.py runs under the real `micropython` (the unix port has
vfs.VfsFat and vfs.VfsLfs2; the 32-bit WebAssembly port has neither, so it is not a
tests/run_micropython.py file): v1 live and v2 staged on a RAM block device, the swap cut
before each of its filesystem operations that change the flash, the device's bytes mounted
again as they are, the boot (the real main.py and the flash's own deployswap) itself cut
before each of its changes, then booted uncut. Every pair must leave a whole v1 or v2 tree
that boots (that tree's ropenode imported).

`block` mode (a cut before each block write, inside one operation) is not run here: see
docs/commissioning.md, "Deploy", for what it shows on FAT and littlefs:
    .venv/bin/micropython -X heapsize=32M tests/firmware/vfs_powercut.py firmware fat block
"""
from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from ropemon.firmware import micropython_command

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tests" / "firmware" / "vfs_powercut.py"


@pytest.mark.parametrize("kind", ["fat", "lfs"])
def test_a_swap_cut_after_any_operation_boots_a_whole_tree(kind):
    r = subprocess.run([micropython_command(), "-X", "heapsize=32M", str(SCRIPT), str(ROOT / "firmware"),
                        kind, "op"], cwd=ROOT, env={"MICROPYPATH": ""}, capture_output=True, text=True,
                       timeout=120)
    out = r.stdout + r.stderr
    m = re.search(r"^RESULT (\w+) op cuts=(\d+) boots=(\d+) failed=(\d+)$", r.stdout, re.M)
    assert r.returncode == 0 and m, out
    assert m.group(1) == kind
    cuts, boots, failed = int(m.group(2)), int(m.group(3)), int(m.group(4))
    fails = [line for line in r.stdout.splitlines() if line.startswith("FAIL")]
    assert failed == 0, "\n".join(fails)
    # every change the swap makes is a cut point (journal, copies to .prev/, renames, clean-up),
    # and each is followed by every cut point of the boot's recovery
    assert cuts >= 30 and boots > 10 * cuts, out[-2000:]
    # the boot rolled swaps forward (a cut after the journal; before it v1 is untouched)
    assert "rolled forward" in r.stdout
