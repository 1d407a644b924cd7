"""json for the mpy32 port (extmod/modjson.c is not in the source it is built from).

The subset MicroPython's json has: loads, load, dumps, dump (separators and sort_keys
accepted); malformed text raises ValueError. Plain Python, so it lives on the heap.
"""

_WS = " \t\n\r"
_ESC = {'"': '"', "\\": "\\", "/": "/", "b": "\b", "f": "\f", "n": "\n", "r": "\r", "t": "\t"}


def _err(i):
    raise ValueError("syntax error in JSON at %d" % i)


def _ws(s, i):
    n = len(s)
    while i < n and s[i] in _WS:
        i += 1
    return i


def _value(s, i):
    i = _ws(s, i)
    if i >= len(s):
        _err(i)
    c = s[i]
    if c == "{":
        d = {}
        i = _ws(s, i + 1)
        if i < len(s) and s[i] == "}":
            return d, i + 1
        while True:
            i = _ws(s, i)
            if i >= len(s) or s[i] != '"':
                _err(i)
            k, i = _string(s, i + 1)
            i = _ws(s, i)
            if i >= len(s) or s[i] != ":":
                _err(i)
            v, i = _value(s, i + 1)
            d[k] = v
            i = _ws(s, i)
            if i < len(s) and s[i] == ",":
                i += 1
            elif i < len(s) and s[i] == "}":
                return d, i + 1
            else:
                _err(i)
    if c == "[":
        a = []
        i = _ws(s, i + 1)
        if i < len(s) and s[i] == "]":
            return a, i + 1
        while True:
            v, i = _value(s, i)
            a.append(v)
            i = _ws(s, i)
            if i < len(s) and s[i] == ",":
                i += 1
            elif i < len(s) and s[i] == "]":
                return a, i + 1
            else:
                _err(i)
    if c == '"':
        return _string(s, i + 1)
    for word, val in (("true", True), ("false", False), ("null", None)):
        if s[i:i + len(word)] == word:
            return val, i + len(word)
    j = i
    n = len(s)
    isfloat = False
    if j < n and s[j] == "-":
        j += 1
    while j < n and s[j] in "0123456789+-.eE":
        if s[j] in ".eE":
            isfloat = True
        j += 1
    if j == i or s[i:j] == "-":
        _err(i)
    try:
        return (float(s[i:j]) if isfloat else int(s[i:j])), j
    except ValueError:
        _err(i)


def _string(s, i):
    out = []
    n = len(s)
    start = i
    while True:
        if i >= n:
            _err(i)
        c = s[i]
        if c == '"':
            out.append(s[start:i])
            return "".join(out), i + 1
        if c == "\\":
            out.append(s[start:i])
            if i + 1 >= n:
                _err(i)
            e = s[i + 1]
            if e == "u":
                try:
                    out.append(chr(int(s[i + 2:i + 6], 16)))
                except ValueError:
                    _err(i)
                i += 6
            elif e in _ESC:
                out.append(_ESC[e])
                i += 2
            else:
                _err(i)
            start = i
        else:
            i += 1


def loads(s):
    if isinstance(s, (bytes, bytearray)):
        s = s.decode()
    v, i = _value(s, 0)
    if _ws(s, i) != len(s):
        _err(i)
    return v


def load(f):
    return loads(f.read())


def _str(s):
    out = ['"']
    for c in s:
        if c == '"' or c == "\\":
            out.append("\\" + c)
        elif c < " ":
            out.append("\\u%04x" % ord(c))
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


def _dump(o, out, item_sep, key_sep, sort_keys):
    if o is None:
        out.append("null")
    elif o is True:
        out.append("true")
    elif o is False:
        out.append("false")
    elif isinstance(o, str):
        out.append(_str(o))
    elif isinstance(o, (int, float)):
        out.append(repr(o))
    elif isinstance(o, dict):
        out.append("{")
        keys = sorted(o) if sort_keys else list(o)
        for n, k in enumerate(keys):
            if n:
                out.append(item_sep)
            out.append(_str(k if isinstance(k, str) else str(k)))
            out.append(key_sep)
            _dump(o[k], out, item_sep, key_sep, sort_keys)
        out.append("}")
    elif isinstance(o, (list, tuple)):
        out.append("[")
        for n, v in enumerate(o):
            if n:
                out.append(item_sep)
            _dump(v, out, item_sep, key_sep, sort_keys)
        out.append("]")
    else:
        raise TypeError("%s is not JSON serializable" % type(o).__name__)


def dumps(obj, separators=None, sort_keys=False):
    item_sep, key_sep = separators or (", ", ": ")
    out = []
    _dump(obj, out, item_sep, key_sep, sort_keys)
    return "".join(out)


def dump(obj, stream, separators=None, sort_keys=False):
    stream.write(dumps(obj, separators, sort_keys))
