"""Declarative config schemas: one way to declare, default and validate every config we read.

    SCHEMA = Section({
        "samples": Num(1, 4096, integer=True, default=4),
        "denoise_quality": Str(choices=("high", "balanced", "fast"), default="balanced"),
        "size": List(Num(1, 8192, integer=True), length=2, default=None, nullable=True),
    })
    cfg = SCHEMA.validate(data, "configs/dataset/small.yaml")   # defaults filled in
    SCHEMA.defaults()                                             # the defaults alone

A bad value raises ConfigError with one line: `<source>: <dotted.field>: <what is wrong>, got <v>`.
Numbers must be finite; names used as folder names must be safe slugs (`Name`).
"""

from __future__ import annotations

import copy
import math
import re

from .errors import ConfigError

MISSING = object()
_SLUG = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$")


def _show(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class Field:
    def __init__(self, default=MISSING, nullable: bool = False):
        self.default = default
        self.nullable = nullable

    def validate(self, value, where: str):
        if value is None and self.nullable:
            return None
        return self.check(value, where)

    def check(self, value, where: str):
        raise NotImplementedError

    def defaults(self):
        return copy.deepcopy(self.default)

    @staticmethod
    def fail(where: str, message: str):
        raise ConfigError(f"{where}: {message}")


class Any(Field):
    def check(self, value, where):
        return value


class Bool(Field):
    def check(self, value, where):
        if not isinstance(value, bool):
            self.fail(where, f"must be true or false, got {_show(value)}")
        return value


def is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class Num(Field):
    """A finite number in [lo, hi] (either may be None); `integer` wants a whole number; `above`
    is an exclusive lower bound."""

    def __init__(self, lo=None, hi=None, integer: bool = False, above=None, **kw):
        super().__init__(**kw)
        self.lo, self.hi, self.integer, self.above = lo, hi, integer, above

    def describe(self) -> str:
        what = "a whole number" if self.integer else "a number"
        if self.above is not None:
            return f"{what} > {self.above}" + (f" and <= {self.hi}" if self.hi is not None else "")
        if self.lo is not None and self.hi is not None:
            return f"{what} in [{self.lo}, {self.hi}]"
        if self.lo is not None:
            return f"{what} >= {self.lo}"
        if self.hi is not None:
            return f"{what} <= {self.hi}"
        return what

    def check(self, value, where):
        ok = is_number(value) and math.isfinite(value)
        if ok and self.integer:
            ok = float(value).is_integer()
        if ok:
            ok = ((self.lo is None or value >= self.lo) and (self.hi is None or value <= self.hi)
                  and (self.above is None or value > self.above))
        if not ok:
            self.fail(where, f"must be {self.describe()}, got {_show(value)}")
        return int(value) if self.integer else float(value)


class Str(Field):
    def __init__(self, choices=None, empty: bool = False, **kw):
        super().__init__(**kw)
        self.choices = tuple(choices) if choices is not None else None
        self.empty = empty

    def check(self, value, where):
        if self.choices is not None:
            if not isinstance(value, str) or value not in self.choices:
                self.fail(where, f"must be one of {', '.join(self.choices)}, got {_show(value)}")
        elif not isinstance(value, str) or not (value or self.empty):
            self.fail(where, f"must be a {'' if self.empty else 'non-empty '}string, got {_show(value)}")
        return value


class Name(Field):
    """A name that becomes a file or folder name: letters, digits, '_', '-', '.', at most 100
    characters, not starting with '.' or '-' (so never '..' or a path)."""

    def check(self, value, where):
        if not isinstance(value, str) or not _SLUG.match(value) or ".." in value:
            self.fail(where, f"must be a name of letters, digits, '_', '-' and '.' (no path, at most 100 characters), got {_show(value)}")
        return value


class Range(Field):
    """[min, max] with lo <= min <= max <= hi; a single number means [v, v]."""

    def __init__(self, lo, hi, **kw):
        super().__init__(**kw)
        self.lo, self.hi = lo, hi

    def check(self, value, where):
        if is_number(value):
            value = [value, value]
        if (not isinstance(value, list) or len(value) != 2 or not all(is_number(v) and math.isfinite(v) for v in value)
                or not self.lo <= value[0] <= value[1] <= self.hi):
            self.fail(where, f"must be [min, max] with {self.lo} <= min <= max <= {self.hi}, got {_show(value)}")
        return [float(v) for v in value]


class List(Field):
    def __init__(self, item: Field, length=None, min_length: int = 1, max_length: int = 10_000, **kw):
        super().__init__(**kw)
        self.item, self.length, self.min_length, self.max_length = item, length, min_length, max_length

    def check(self, value, where):
        n = f"{self.length}" if self.length else f"{self.min_length} or more"
        if not isinstance(value, list) or (self.length and len(value) != self.length) or not self.min_length <= len(value) <= self.max_length:
            self.fail(where, f"must be a list of {n} items, got {_show(value)}")
        return [self.item.validate(v, f"{where}[{i}]") for i, v in enumerate(value)]


class Mapping(Field):
    """A mapping with free keys (checked by `key`) and values checked by `value`."""

    def __init__(self, key: Field, value: Field, **kw):
        super().__init__(**kw)
        self.key, self.value = key, value

    def check(self, value, where):
        if not isinstance(value, dict):
            self.fail(where, f"must be a mapping, got {_show(value)}")
        return {self.key.validate(k, f"{where}"): self.value.validate(v, f"{where}.{k}") for k, v in value.items()}


class OneOf(Field):
    """The first alternative that accepts the value; else one message listing what was wanted."""

    def __init__(self, *alternatives: Field, wanted: str, **kw):
        super().__init__(**kw)
        self.alternatives, self.wanted = alternatives, wanted

    def check(self, value, where):
        for a in self.alternatives:
            try:
                return a.validate(value, where)
            except ConfigError:
                continue
        self.fail(where, f"must be {self.wanted}, got {_show(value)}")


class Section(Field):
    """A mapping of named fields. Missing fields take their default (a field without one is
    required); unknown fields are refused. A `partial` section keeps only the fields given."""

    def __init__(self, fields: dict, partial: bool = False, **kw):
        kw.setdefault("default", None)
        super().__init__(**kw)
        self.fields, self.partial = fields, partial

    def defaults(self) -> dict:
        if self.partial:
            return {}
        return {k: f.defaults() for k, f in self.fields.items() if f.default is not MISSING}

    def validate(self, value, where: str, base: dict | None = None):
        """`where` is the source (file) for the top section, else `file: dotted.path`."""
        if value is None and self.nullable:
            return None
        return self.check(value, where, base)

    def check(self, value, where, base=None):
        if not isinstance(value, dict):
            self.fail(where, f"must be a mapping, got {_show(value)}")
        out = self.defaults() if base is None else copy.deepcopy(base)
        for k, v in value.items():
            sub = _join(where, k)
            if k not in self.fields:
                self.fail(sub, f"unknown field (known: {', '.join(map(str, self.fields))})")
            out[k] = self.fields[k].validate(v, sub)
        for k, f in self.fields.items():
            if k not in out and not self.partial:
                self.fail(_join(where, k), "missing")
        return out


def _join(where: str, key) -> str:
    """'file.yaml' + 'a' -> 'file.yaml: a'; 'file.yaml: a' + 'b' -> 'file.yaml: a.b'."""
    return f"{where}.{key}" if ": " in where else f"{where}: {key}"


def deep_merge(base: dict, over: dict, atomic=("grid",)) -> dict:
    """`over` merged into a copy of `base`, mapping by mapping (keys in `atomic` are replaced whole)."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        out[k] = deep_merge(out[k], v, atomic) if isinstance(v, dict) and isinstance(out.get(k), dict) and k not in atomic else copy.deepcopy(v)
    return out
