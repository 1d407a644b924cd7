"""deployswap on a board's filesystems, cut by a power loss at every step (MicroPython only).

Run by tests/firmware/test_deployswap_vfs_cpython.py as
    micropython tests/firmware/vfs_powercut.py FIRMWARE_DIR fat|lfs op|block
(not a test file of tests/run_micropython.py: it needs the unix port's vfs.VfsFat /
vfs.VfsLfs2, which the 32-bit WebAssembly port lacks).

A RAM block device holds a node's flash: firmware v1 live, v2 staged in `.staged/` (as
deploy leaves it before the swap). It is mounted through `CutFs`, a VFS that forwards to
the real VfsFat or VfsLfs2 and loses power before its Nth write:

- `op`:    N counts filesystem operations that change the flash (open for writing, write,
           close of a written file, rename, remove, mkdir, rmdir);
- `block`: N counts the block device's block writes (a cut inside one operation: the
           write and all after it are lost; the code stops at its next operation).

At the cut the device's bytes are kept as they are; nothing after it reaches them. They
are mounted again and the node boots as a board does (boot.py, then main.py, from the
filesystem: the real main.py, which runs the flash's own deployswap.finish before it
imports ropenode), itself cut at every step M of its recovery, then booted once more
uncut. Every (N, M) must end with a whole v1 or v2 tree (every file's bytes), no journal
or staging left, and the boot must have imported that tree's ropenode.

Prints one line per failure (`FAIL ...`) and last `RESULT kind mode cuts=.. boots=.. failed=..`.
"""
import os
import sys
import vfs

FIRMWARE = sys.argv[1]
KIND = sys.argv[2]
MODE = sys.argv[3]
MAX_FAIL_LINES = 20
MNT = "/flash"


class PowerCut(BaseException):
    """The node lost power (not an OSError/Exception: no code on the node may catch it)."""


class RamBlockDev:
    """The extended block protocol (readblocks/writeblocks with offset, ioctl erase) over a bytearray."""

    def __init__(self, data, block_size=512):
        self.bs = block_size
        self.data = data
        self.cut = None  # Cutter counting block writes, in `block` mode

    def readblocks(self, n, buf, off=0):
        a = n * self.bs + off
        try:
            buf[:] = self.data[a:a + len(buf)]
        except MemoryError:  # littlefs closing a file dropped at a cut, from the GC (heap locked)
            d = self.data
            for i in range(len(buf)):
                buf[i] = d[a + i]

    def writeblocks(self, n, buf, off=None):
        if self.cut is not None and not self.cut.block_write(self):
            return  # the power is off: the write goes nowhere (no exception through the C driver)
        a = n * self.bs + (off or 0)
        self.data[a:a + len(buf)] = buf

    def ioctl(self, op, arg):
        if op == 4:
            return len(self.data) // self.bs
        if op == 5:
            return self.bs
        if op == 6:  # erase a block, as flash does (to 0xFF); lost after the cut too
            if self.cut is None or self.cut.block_write(self):
                a = arg * self.bs
                for i in range(a, a + self.bs):
                    self.data[i] = 0xFF
            return 0
        return None


class Cutter:
    """Loses power before write number `at` (None: never); keeps the device's bytes then.
    Allocation-free once built: littlefs writes from the GC's finaliser (a file left open
    at the cut), with the heap locked."""

    def __init__(self, at, size):
        self.at = at
        self.n = 0
        self.snapshot = None
        self.buf = bytearray(size) if at is not None else None
        self.exc = PowerCut()

    def step(self, bd):
        if self.snapshot is not None:
            raise self.exc
        if self.at is not None and self.n == self.at:
            self.buf[:] = bd.data
            self.snapshot = self.buf
            raise self.exc
        self.n += 1

    def block_write(self, bd):
        """`block` mode: False from the cut on (the write is lost); the code above learns of
        it at its next filesystem operation (CutFs.op raises)."""
        if self.snapshot is not None:
            return False
        if self.at is not None and self.n == self.at:
            self.buf[:] = bd.data
            self.snapshot = self.buf
            return False
        self.n += 1
        return True


class CutFile:
    """A file open for writing on CutFs: write and close are steps."""

    def __init__(self, fs, f):
        self.fs = fs
        self.f = f

    def write(self, b):
        self.fs.op()
        return self.fs.do(self.f.write, b)

    def close(self):
        if self.f is not None:
            f, self.f = self.f, None
            self.fs.op()
            self.fs.do(f.close)

    def __enter__(self):
        return self

    def __exit__(self, *a):
        self.close()


class CutFs:
    """A VFS forwarding to a real one; in `op` mode every change is a step of the Cutter."""

    def __init__(self, real, bd, cutter):
        self.real = real
        self.bd = bd
        self.cutter = cutter
        if MODE == "block":
            bd.cut = cutter

    def op(self):
        if MODE == "op":
            self.cutter.step(self.bd)
        elif self.cutter.snapshot is not None:
            raise PowerCut

    def do(self, f, *a):
        """Run a real operation; an error it raises after the power went is the cut."""
        try:
            return f(*a)
        except OSError:
            if self.cutter.snapshot is not None:
                raise PowerCut
            raise

    def mount(self, readonly, mkfs):
        self.real.mount(readonly, mkfs)

    def umount(self):
        self.real.umount()

    def open(self, path, mode):
        if "w" in mode or "a" in mode or "+" in mode:
            self.op()
            return CutFile(self, self.do(self.real.open, path, mode))
        return self.real.open(path, mode)

    def ilistdir(self, path):
        return self.real.ilistdir(path)

    def stat(self, path):
        return self.real.stat(path)

    def statvfs(self, path):
        return self.real.statvfs(path)

    def chdir(self, path):
        self.real.chdir(path)

    def getcwd(self):
        return self.real.getcwd()

    def rename(self, a, b):
        self.op()
        self.do(self.real.rename, a, b)

    def remove(self, p):
        self.op()
        self.do(self.real.remove, p)

    def mkdir(self, p):
        self.op()
        self.do(self.real.mkdir, p)

    def rmdir(self, p):
        self.op()
        self.do(self.real.rmdir, p)


def _vfs_class():
    return vfs.VfsFat if KIND == "fat" else vfs.VfsLfs2


def mount(data, cutter):
    bd = RamBlockDev(data)
    fs = CutFs(_vfs_class()(bd), bd, cutter)
    vfs.mount(fs, MNT)
    os.chdir(MNT)
    return fs


def unmount():
    os.chdir("/")
    try:
        vfs.umount(MNT)
    except (OSError, PowerCut):
        pass  # the device's bytes at the cut are what counts; the dead mount is dropped


# --- the two firmware versions: the real main.py and deployswap.py, a stub board HAL

def _read(p):
    with open(p) as f:
        return f.read()


MAIN = _read(FIRMWARE + "/main.py")
SWAP = _read(FIRMWARE + "/deployswap.py")
HAL = 'VERSION = %r\n\ndef run(path):\n    raise SystemExit("booted " + VERSION)\n'


def version_tree(v):
    """{path: bytes} of firmware version v (every file differs between versions; a file
    only v1 has and one only v2 has, so a mix of the two is seen)."""
    t = {
        "main.py": MAIN + "# version %s\n" % v,
        "deployswap.py": SWAP + "# version %s\n" % v,
        "node.json": '{"version": "%s"}\n' % v,
        "ropenode/__init__.py": "FIRMWARE_VERSION = %r\n" % v,
        "ropenode/hal_board.py": HAL % v,
        "ropenode/kernel.py": "K = %r\n" % (v * 300),
    }
    if v == "1":
        t["ropenode/old_only.py"] = "X = 1\n"
    else:
        t["ropenode/new_only.py"] = "X = 2\n"
        t["new_item.txt"] = "only in version 2\n"
    return t


def write_tree(prefix, tree):
    for p in sorted(tree):
        parts = (prefix + p).split("/")
        for i in range(1, len(parts)):
            d = "/".join(parts[:i])
            try:
                os.mkdir(d)
            except OSError:
                pass
        with open(prefix + p, "w") as f:
            f.write(tree[p])


def read_tree(d=""):
    """{path: text} of the live tree (the deploy's own dot-entries left out, reported by check)."""
    out = {}
    for e in os.ilistdir(d or "."):
        name = e[0]
        p = d + "/" + name if d else name
        if not d and name.startswith("."):
            continue
        if e[1] & 0x4000:
            out.update(read_tree(p))
        else:
            out[p] = _read(p)
    return out


def dot_entries():
    return [e[0] for e in os.ilistdir(".") if e[0].startswith(".")]


def ready_image():
    """The flash as deploy leaves it before the swap: v1 live, v2 staged and verified."""
    data = bytearray(512 * 192)
    bd = RamBlockDev(data)
    _vfs_class().mkfs(bd)
    mount(data, Cutter(None, 0))
    write_tree("", version_tree("1"))
    os.mkdir(".staged")
    write_tree(".staged/", version_tree("2"))
    unmount()
    return data


def swap_module():
    """The laptop's deployswap (deploy sends its source), not the one on the flash."""
    ns = {"__name__": "deployswap_host"}
    exec(SWAP, ns)
    return ns


def purge_modules():
    for m in list(sys.modules):
        if m in ("deployswap", "main", "time") or m == "ropenode" or m.startswith("ropenode."):
            del sys.modules[m]


class _Time:
    """`time` for main.py: its restart after a failed board loop (sleep) ends the boot."""

    @staticmethod
    def sleep(s):
        raise SystemExit("main.py's board loop failed (it would restart it every second)")


def boot():
    """A board's reset: boot.py then main.py from the flash. Returns the version booted,
    or a description of what went wrong. A PowerCut propagates."""
    purge_modules()
    sys.modules["time"] = _Time
    ran = False
    out = None
    for f in ("boot.py", "main.py"):
        try:
            src = _read(f)
        except OSError:
            continue
        ran = True
        try:
            exec(src, {"__name__": "__main__"})
        except SystemExit as e:
            out = e.args[0] if e.args else "exit"
            break
    purge_modules()
    if not ran:
        return "no boot.py or main.py: the board stops at the REPL"
    return out or "main.py returned"


def check(tag, want_any, trees):
    """A whole v1 or v2 tree, nothing of the deploy left, and the boot ran that version."""
    try:
        live = read_tree()
    except OSError as e:
        return "%s: the filesystem is damaged: reading the tree: %r" % (tag, e)
    for v in want_any:
        if live == trees[v]:
            # v1 with `.staged/`: cut before the journal, the swap never began (the next
            # deploy clears it); `.prev/` stays until the next deploy
            dots = [d for d in dot_entries() if d not in (".prev", ".staged" if v == "1" else ".prev")]
            if dots:
                return "%s: %s left" % (tag, dots)
            return None
    which = {}
    for p in sorted(set(live) | set(trees["1"]) | set(trees["2"])):
        w = "".join(v for v in ("1", "2") if live.get(p) == trees[v].get(p))
        which[p] = w or "?"
    diff = " ".join("%s:%s" % (p, which[p]) for p in sorted(which))
    return "%s: neither v1 nor v2: %s" % (tag, diff)


def main():
    sys.path[:] = ["", ".frozen"]  # a board's: the flash's own modules, never the repo's
    trees = {"1": version_tree("1"), "2": version_tree("2")}
    ready = ready_image()
    ds = swap_module()
    names = sorted(set(p.split("/")[0] for p in trees["2"]))
    failed = []
    cuts = 0
    boots = 0
    n = 0
    while True:
        # the swap, cut before its nth write
        cut = Cutter(n, len(ready))
        mount(bytearray(ready), cut)
        try:
            ds["swap"](names)
        except PowerCut:
            pass
        unmount()
        if cut.snapshot is None:  # ran to its end uncut: every cut point is covered
            break
        cuts += 1
        after_swap = cut.snapshot
        m = 0
        while True:
            # the boot's recovery, cut before its mth write; then an uncut boot
            cut2 = Cutter(m, len(ready))
            img = bytearray(after_swap)
            mount(img, cut2)
            first = None
            try:
                first = boot()
            except PowerCut:
                pass
            unmount()
            uncut = cut2.snapshot is None
            # the flash as the cut left it (or as the uncut boot left it), booted again uncut
            mount(img if uncut else cut2.snapshot, Cutter(None, 0))
            mount_ok = first if uncut else None
            booted = boot()
            boots += 1
            tag = "%s %s: swap cut before write %d, boot cut before write %s" % (
                KIND, MODE, n, "-" if uncut else m)
            why = None
            if mount_ok is not None and not mount_ok.startswith("booted "):
                why = "%s: first boot: %s" % (tag, mount_ok)
            elif not booted.startswith("booted "):
                why = "%s: boot: %s" % (tag, booted)
            else:
                why = check(tag, ("1", "2"), trees)
                if why is None:
                    live_v = "1" if read_tree() == trees["1"] else "2"
                    if booted != "booted " + live_v:
                        why = "%s: booted %s with tree v%s" % (tag, booted, live_v)
            unmount()
            if why:
                failed.append(why)
                if len(failed) <= MAX_FAIL_LINES:
                    print("FAIL", why)
            if uncut:
                break
            m += 1
        n += 1
    print("RESULT %s %s cuts=%d boots=%d failed=%d" % (KIND, MODE, cuts, boots, len(failed)))


main()
