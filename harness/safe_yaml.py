"""Reading YAML that a user (or anyone who can write a file the user runs) wrote: bounded and strict.

``yaml.safe_load`` already refuses Python tags, but it expands aliases without limit (a few hundred bytes of
``&a [*a, *a, ...]`` lists become gigabytes once anything walks them), accepts a key written twice (the last
one silently wins), turns a 5000-digit integer into a ``ValueError`` traceback, and builds recursive lists from
``&a [*a]``. ``load`` composes the document first, measures it with every alias expanded (values, depth,
cycles) before anything is constructed, then constructs it with duplicate keys and oversized integers refused.
Every refusal is one line naming the file and, where the parser knows it, the line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from harness.io import read_input_bytes

MAX_NODES = 100_000        # values after expanding aliases (a scenario has a few hundred; a sweep of 20,000
                           # values is 20,000)
MAX_DEPTH = 32             # nesting of mappings and lists (a scenario nests four deep)
MAX_INT_DIGITS = 19        # 2**63 has 19 digits: every integer a scenario means fits in 63 bits
MAX_INT = 2**63 - 1

_BASE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)   # libyaml's parser when present: 5x faster
_MERGE = "tag:yaml.org,2002:merge"
_INT = "tag:yaml.org,2002:int"


class _Refused(yaml.YAMLError):
    def __init__(self, problem: str, mark=None):
        super().__init__(problem)
        self.problem, self.problem_mark = problem, mark


class _StrictLoader(_BASE):
    """The safe loader with duplicate keys and integers beyond 63 bits refused."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: set = set()
            for key_node, _ in node.value:
                if key_node.tag == _MERGE:          # merged keys may be overridden: that is what '<<' is for
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                except TypeError:                   # an unhashable key: the base constructor names it
                    break
                if duplicate:
                    raise _Refused(f"key {_short(key)} is given twice", key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _construct_int(loader: _StrictLoader, node: yaml.ScalarNode) -> int:
    digits = sum(ch.isalnum() for ch in node.value)
    if digits > MAX_INT_DIGITS + 2:                 # '0x', '0o' prefixes; checked before int() parses it
        raise _Refused(f"integer with {digits} digits is too large (at most {MAX_INT})", node.start_mark)
    value = yaml.SafeLoader.construct_yaml_int(loader, node)
    if abs(value) > MAX_INT:
        raise _Refused(f"integer {value} is too large (at most {MAX_INT})", node.start_mark)
    return value


_StrictLoader.add_constructor(_INT, _construct_int)


def _short(value: Any, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _measure(root: yaml.Node) -> None:
    """Refuse a document with more than ``MAX_NODES`` values once aliases are expanded, nested deeper than
    ``MAX_DEPTH``, or recursive (an alias inside its own anchor). Iterative, and linear in the number of
    distinct nodes: each node's expanded size is computed once (an alias is a second reference to a node)."""
    size: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, int, bool]] = [(root, 1, False)]
    while stack:
        node, depth, done = stack.pop()
        key = id(node)
        if done:
            on_path.discard(key)
            children = _children(node)
            size[key] = 1 + sum(size[id(c)] for c in children)
            if size[key] > MAX_NODES:
                raise _Refused(f"more than {MAX_NODES} values once aliases are expanded", node.start_mark)
            continue
        if key in size:
            continue
        if key in on_path:
            raise _Refused("an alias refers to a value that contains it (a recursive document)", node.start_mark)
        if depth > MAX_DEPTH:
            raise _Refused(f"nested more than {MAX_DEPTH} levels deep", node.start_mark)
        on_path.add(key)
        stack.append((node, depth, True))
        for child in _children(node):
            if id(child) in on_path:
                raise _Refused("an alias refers to a value that contains it (a recursive document)",
                               child.start_mark)
            if id(child) not in size:
                stack.append((child, depth + 1, False))


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def parse(text: str, where: str, error: type[Exception]) -> Any:
    """The value of one YAML document ``text`` (None when empty); ``error(message)`` names ``where`` and the
    line for anything malformed, oversized, recursive, with a duplicate key or a Python tag."""
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        _measure(node)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = f" line {mark.line + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or type(exc).__name__).split())
        raise error(f"{where}:{line} not valid YAML ({problem})") from None
    except RecursionError:
        raise error(f"{where}: not valid YAML (nested too deeply)") from None
    finally:
        loader.dispose()


def load(path: str | Path, error: type[Exception], kind: str, max_bytes: int) -> Any:
    """Read and ``parse`` a YAML file of at most ``max_bytes`` (checked before reading; FIFOs and devices are
    refused), UTF-8 without NUL bytes."""
    data = read_input_bytes(path, error, kind, max_bytes)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not a text file (byte {exc.start} is not UTF-8)") from None
    if "\x00" in text:
        raise error(f"{path}: not a text file (it contains NUL bytes)")
    return parse(text, str(path), error)
