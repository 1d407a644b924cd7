"""Edit one field of a nested config document, for tests that refuse bad fields one by one."""
from __future__ import annotations

import copy


def edited(doc: dict, path: str, value=..., delete: bool = False) -> dict:
    """A copy of doc with one dotted field set (or deleted); list items as [i]."""
    d = copy.deepcopy(doc)
    keys = path.replace("[", ".[").split(".")
    node = d
    for k in keys[:-1]:
        node = node[int(k[1:-1])] if k.startswith("[") else node[k]
    last = keys[-1]
    last = int(last[1:-1]) if last.startswith("[") else last
    if delete:
        del node[last]
    else:
        node[last] = value
    return d
