"""Settings declared once: each field of a frozen settings dataclass carries its default, unit, allowed values and
meaning, and is checked against them when the object is built.

``setting(default, unit, bounds, meaning)`` declares a field; ``bounds`` is an interval in the usual notation
(``"(0, 1]"``, ``"[1, 1000]"``, ``"> 0"``, ``">= 0"``; empty: any finite number, or any bool for a bool field),
applied to every element of a tuple. ``size`` bounds a tuple's length (an int: exactly; ``(lo, hi)``: within),
``ordered`` asks its elements to increase (``"<"``) or not decrease (``"<="``). ``check_fields`` checks an object
against its declarations, and ``values_text`` writes the allowed values the way the schema documentation shows
them. A renamed setting keeps its former name in ``was`` (so that an old key is refused with its new place).
"""

from __future__ import annotations

import math
import re
import typing
from dataclasses import dataclass, field, fields
from functools import lru_cache

_INTERVAL = re.compile(r"^([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])$")
_ONE_SIDED = re.compile(r"^(>=|>|<=|<)\s*(\S+)$")


@dataclass(frozen=True)
class Bounds:
    """An interval of the real line; ``None`` ends are open to infinity."""

    low: float | None = None
    high: float | None = None
    low_closed: bool = False
    high_closed: bool = False

    @classmethod
    def parse(cls, text: str) -> Bounds:
        text = text.strip()
        if not text:
            return cls()
        if m := _INTERVAL.match(text):
            lo, hi = (None if v in ("-inf", "inf") else float(v) for v in m.group(2, 3))
            return cls(lo, hi, m.group(1) == "[", m.group(4) == "]")
        if m := _ONE_SIDED.match(text):
            op, v = m.group(1), float(m.group(2))
            return cls(v, None, op == ">=") if op.startswith(">") else cls(None, v, False, op == "<=")
        raise ValueError(f"cannot read bounds {text!r}")

    def admits(self, v: float) -> bool:
        above = self.low is None or (v >= self.low if self.low_closed else v > self.low)
        below = self.high is None or (v <= self.high if self.high_closed else v < self.high)
        return above and below

    def __str__(self) -> str:
        def num(v: float) -> str:
            return str(int(v)) if float(v).is_integer() else f"{v:g}"

        if self.low is None and self.high is None:
            return "finite"
        if self.high is None:
            return f"{'>=' if self.low_closed else '>'} {num(self.low)}"
        if self.low is None:
            return f"{'<=' if self.high_closed else '<'} {num(self.high)}"
        return f"{'[' if self.low_closed else '('}{num(self.low)}, {num(self.high)}{']' if self.high_closed else ')'}"

    @property
    def phrase(self) -> str:
        """``in (0, 1]``, ``> 0`` or ``finite``: what a value must be."""
        text = str(self)
        return f"in {text}" if text[0] in "[(" else text


def setting(default, unit: str, bounds: str, meaning: str, *, size: int | tuple[int, int] | None = None,
            ordered: str | None = None, was: str | None = None):
    """A settings field with its declaration (module docstring)."""
    if isinstance(default, (list, dict, set)):
        raise TypeError("mutable default")
    return field(default=default, metadata={"unit": unit, "bounds": Bounds.parse(bounds), "meaning": meaning,
                                            "size": size, "ordered": ordered, "was": was})


@lru_cache(maxsize=None)
def _kinds(cls: type) -> dict[str, type]:
    """Each field's scalar kind (``bool``, ``int`` or ``float``; a tuple's element kind)."""
    out = {}
    for name, ann in typing.get_type_hints(cls).items():
        if typing.get_origin(ann) is tuple:
            ann = typing.get_args(ann)[0]
        out[name] = ann
    return out


def _problem(value, kind: type, meta: dict) -> str | None:
    """What is wrong with ``value`` for a field of scalar ``kind`` and declaration ``meta``, or None."""
    size, ordered = meta["size"], meta["ordered"]
    items = value if size is not None else (value,)
    if size is not None:
        if not isinstance(value, tuple):
            return "must be a list of numbers"
        lo, hi = (size, size) if isinstance(size, int) else size
        if not lo <= len(value) <= hi:
            return f"must list {lo} numbers" if lo == hi else f"must list {lo} to {hi} numbers"
    for v in items:
        if kind is bool:
            if not isinstance(v, bool):
                return "must be true or false"
            continue
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return "must be a finite number" if size is None else "must be finite numbers"
        if kind is int and not isinstance(v, int):
            return "must be an integer"
        if not meta["bounds"].admits(v):
            return f"must be {meta['bounds'].phrase}" + ("" if size is None else " each")
    if ordered and any(not (a < b if ordered == "<" else a <= b) for a, b in zip(items, items[1:])):
        return "must increase" if ordered == "<" else "must not decrease"
    return None


def check_fields(obj, prefix: str, error: type[Exception]) -> None:
    """Check every declared field of ``obj``; raises ``error("<prefix>.<name> must ..., got <value>")`` with the
    parts as its ``key`` (the field's name), ``why`` and ``value``."""
    kinds = _kinds(type(obj))
    for f in fields(obj):
        value = getattr(obj, f.name)
        why = _problem(value, kinds[f.name], f.metadata)
        if why:
            shown = list(value) if isinstance(value, tuple) else value
            exc = error(f"{prefix}.{f.name} {why}, got {shown!r}")
            exc.key, exc.why, exc.value = f.name, why, shown     # for callers that word it their own way
            raise exc


def values_text(cls: type, f) -> str:
    """The allowed values of field ``f`` of ``cls`` as the schema documentation writes them."""
    meta, kind = f.metadata, _kinds(cls)[f.name]
    if kind is bool:
        return "true, false"
    text = ("int " if kind is int else "") + meta["bounds"].phrase
    size = meta["size"]
    if size is None:
        return text
    count = str(size) if isinstance(size, int) else f"{size[0]}-{size[1]}"
    order = {"<": ", increasing", "<=": ", non-decreasing"}.get(meta["ordered"], "")
    return f"{count} numbers, each {text}{order}"


class SectionBase:
    """A frozen settings section, checked against its declarations when built. Subclasses name themselves by
    class keywords: ``label`` and ``error`` (what a failed check says and raises) once for a family of sections,
    ``name`` per section, so that a message reads ``<label> <name>.<field> must ...``."""

    name: str = ""
    label: str = "setting"
    error: type[Exception] = ValueError

    def __init_subclass__(cls, name: str = "", label: str = "", error: type[Exception] | None = None, **kw):
        super().__init_subclass__(**kw)
        cls.name, cls.label, cls.error = name or cls.name, label or cls.label, error or cls.error

    def __post_init__(self):
        check_fields(self, f"{self.label} {self.name}", self.error)


def section_types(composite: type) -> dict[str, type]:
    """The section classes of a composite settings dataclass, by field name."""
    hints = typing.get_type_hints(composite)
    return {f.name: hints[f.name] for f in fields(composite)}


def former_names(composite: type) -> dict[str, str]:
    """Each setting's flat name before the sections (``was``, else its own name) with its ``section.field``."""
    return {f.metadata["was"] or f.name: f"{name}.{f.name}" for name, kind in section_types(composite).items()
            for f in fields(kind)}


def unknown_key(composite: type, key: str, what: str) -> str:
    """The message for a ``key`` that names no setting (a former flat name: where it went)."""
    moved = former_names(composite).get(key)
    if moved:
        return f"{what} {key} moved to {moved}"
    return f"unknown {what} {key} (sections: {', '.join(section_types(composite))})"


def from_sections(composite: type, values: dict, error: type[Exception], what: str):
    """A composite built from ``{section: {field: value}}`` or ``{"section.field": value}`` (the rest at their
    defaults); an unknown or former key raises ``error`` with ``unknown_key``'s message."""
    kinds = section_types(composite)
    nested: dict = {}
    for key, value in values.items():
        section, dot, name = key.partition(".")
        if dot:
            nested.setdefault(section, {})[name] = value
        else:
            nested.setdefault(key, {}).update(value if isinstance(value, dict) else {None: value})
    built = {}
    for section, items in nested.items():
        if section not in kinds or None in items:
            raise error(unknown_key(composite, section, what))
        names = {f.name for f in fields(kinds[section])}
        for key in items:
            if key not in names:
                raise error(unknown_key(composite, f"{section}.{key}", what))
        built[section] = kinds[section](**items)
    return composite(**built)


def parse_assignments(composite: type, items: list[str], error: type[Exception], what: str) -> dict:
    """``["section.field=value", ...]`` (settings typed on a command line) as ``{section: {field: value}}``, each
    value read as its field's kind (bools as true/false, yes/no, 1/0; tuples comma-separated)."""
    kinds, out = section_types(composite), {}
    for item in items:
        key, sep, text = item.partition("=")
        section, _, name = key.partition(".")
        if not sep:
            raise error(f"{what} {item!r}: expected SECTION.FIELD=VALUE")
        if section not in kinds or name not in {f.name for f in fields(kinds[section])}:
            raise error(unknown_key(composite, key, what))
        kind = _kinds(kinds[section])[name]
        tuple_field = next(f for f in fields(kinds[section]) if f.name == name).metadata["size"] is not None
        try:
            if kind is bool:
                value = {"true": True, "1": True, "yes": True, "false": False, "0": False, "no": False}[text.lower()]
            elif tuple_field:
                value = tuple(float(v) for v in text.split(",") if v)
            else:
                value = kind(text)
        except (KeyError, ValueError):
            raise error(f"{what} {key}: cannot read {text!r} as {kind.__name__}") from None
        out.setdefault(section, {})[name] = value
    return out
