"""The node side of `ropemon deploy`'s swap, and its completion at boot (main.py).

Deploy stages every new item (`main.py`, `ropenode/`, `node.json`, ...) in
`.staged/`, verifies it by hash, then calls `swap(names)`: the journal
`.deploy-swap` (the names, in order) is written atomically, each live item is
kept in `.prev/` (a file copied, a directory moved) and its staged copy renamed
into place, then the journal is removed.
This module is the one copy of that logic: deploy sends its source over the
REPL, and main.py imports it before `ropenode`, so a swap cut by a power loss
is finished at the next boot:

- roll forward when every item not yet swapped is still staged (the normal
  case: the staged set was verified before the journal was written);
- otherwise roll back: the swapped items get their `.prev/` copies back (an
  item with no previous version is removed), so the node never runs a mix.

Items are swapped in journal order, so the swapped ones are exactly those
before the first item still in `.staged/`. Paths are relative to the current
directory (`/` on a board after reset). Plain MicroPython: os and json only.
"""
import json
import os

JOURNAL = ".deploy-swap"
STAGED = ".staged"
PREV = ".prev"


def _kind(p):
    """True for a directory, False for a file, None if absent."""
    try:
        return os.stat(p)[0] & 0x4000 != 0
    except OSError:
        return None


def _rmtree(p):
    d = _kind(p)
    if d is None:
        return
    if d:
        for e in list(os.ilistdir(p)):  # listed first: deleting while iterating may skip entries
            _rmtree(p + "/" + e[0])
        os.rmdir(p)
    else:
        os.remove(p)


def _replace(src, dst):
    """Rename src over dst. A file over a file is one atomic rename on POSIX and littlefs;
    MicroPython's VfsFat removes dst itself inside that rename (FAT cannot do it atomically);
    a filesystem that refuses takes the remove-then-rename below."""
    if _kind(dst):
        _rmtree(dst)
    try:
        os.rename(src, dst)
    except OSError:
        if _kind(dst) is None:
            raise
        os.remove(dst)
        os.rename(src, dst)


def _copy(src, dst):
    buf = bytearray(512)
    with open(src, "rb") as fi:
        with open(dst, "wb") as fo:
            while True:
                n = fi.readinto(buf)
                if not n:
                    break
                fo.write(buf if n == len(buf) else memoryview(buf)[:n])


def read_journal():
    """The journal's item names; None without a journal; [] if it is unreadable."""
    if _kind(JOURNAL) is None:
        return None
    try:
        with open(JOURNAL) as f:
            names = json.loads(f.read())
        if isinstance(names, list) and all(isinstance(n, str) and n and "/" not in n for n in names):
            return names
    except (OSError, ValueError):
        pass
    return []


def swap(names):
    """Journal, then swap the staged items in (deploy calls this once staging is verified)."""
    tmp = JOURNAL + ".tmp"
    with open(tmp, "w") as f:
        f.write(json.dumps(names))
    os.rename(tmp, JOURNAL)  # atomic: no journal, or a whole one
    roll_forward(names)


def can_roll_forward(names):
    """True if every item is either swapped in already or still staged (see the docstring)."""
    staged_seen = False
    for n in names:
        if _kind(STAGED + "/" + n) is not None:
            staged_seen = True
        elif staged_seen or _kind(n) is None:
            return False
    return True


def roll_forward(names):
    """Finish the swap; idempotent, so a cut here is finished by the next call."""
    if _kind(PREV) is None:
        os.mkdir(PREV)
    for n in names:
        staged = STAGED + "/" + n
        if _kind(staged) is None:
            continue  # swapped in already
        live = _kind(n)
        if live:  # a directory: moved aside (a cut here is completed by main.py at boot)
            _replace(n, PREV + "/" + n)
        elif live is False:  # a file: copied aside, then replaced in one rename, so main.py
            _copy(n, PREV + "/" + n)  # itself is never missing
        _replace(staged, n)
    _done()


def roll_back(names):
    """Undo the swapped items (those before the first still staged) from `.prev/`."""
    for n in names:
        if _kind(STAGED + "/" + n) is not None:  # the first item not swapped yet: it may be
            if _kind(n) is None and _kind(PREV + "/" + n) is not None:  # half-moved to .prev
                os.rename(PREV + "/" + n, n)
            break
        if _kind(PREV + "/" + n) is not None:
            _replace(PREV + "/" + n, n)
        else:
            _rmtree(n)  # new in this deploy: no previous version to go back to
    _done()
    _rmtree(PREV)  # emptied: every previous item is live again


def _done():
    _rmtree(STAGED)  # before the journal: a cut in here is finished by the next call
    os.remove(JOURNAL)


def finish():
    """At boot: complete an interrupted swap. Returns None (none pending), "forward" or "back"."""
    _rmtree(JOURNAL + ".tmp")  # a journal never renamed into place: the swap had not begun
    names = read_journal()
    if names is None:
        return None
    if names and can_roll_forward(names):
        roll_forward(names)
        return "forward"
    if not names:  # unreadable journal: put back whatever .prev/ holds
        names = [e[0] for e in os.ilistdir(PREV)] if _kind(PREV) else []
        for n in names:
            _replace(PREV + "/" + n, n)
        _done()
        _rmtree(PREV)
        return "back"
    roll_back(names)
    return "back"
