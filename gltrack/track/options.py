"""The options convention shared by every tracker.

A tracker's options are a dataclass deriving from :class:`Options`: its fields are the
method's ``--config`` keys, :meth:`Options.problems` lists the values outside their domain (each
subclass extends its parent's list) and :meth:`Options.validate` raises one ``ValueError`` naming
every bad key. Trackers validate their options once, when they are built; a config file is read
with :meth:`Options.from_dict`, which also rejects unknown keys and wrong types.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar


@dataclass
class Options:
    """Base of the trackers' options dataclasses.

    Class attributes
    ----------------
    FLAGS : dict, command-line flag (``gltrack track --FLAG``) -> the option it sets, where the
        names differ (e.g. ``--behaviour`` sets ``model`` of the vlmm tracker)
    IMPLIES : dict, option -> {other option: value} set (unless given) when the option is set
        from a command-line flag; e.g. a behaviour model given to a multi-view tracker implies
        its ``prior = "vlmm"``
    """

    FLAGS: ClassVar[dict] = {}
    IMPLIES: ClassVar[dict] = {}

    def problems(self) -> list[str]:
        """Descriptions (``"key = value (why)"``) of options outside their domain; [] if none."""
        return []

    def validate(self):
        """Raise ``ValueError`` naming every option outside its domain; return ``self``."""
        bad = self.problems()
        if bad:
            raise ValueError(f"invalid {type(self).__name__} option(s): " + "; ".join(bad))
        return self

    @classmethod
    def keys(cls) -> list[str]:
        """The option names (``--config`` keys), in declaration order."""
        return [f.name for f in dataclasses.fields(cls)]

    @classmethod
    def from_dict(cls, values: dict | None, where: str = "config"):
        """Build and validate the options from a dict (a ``--config`` table).

        Unknown keys and values of the wrong type are errors that name the key and ``where``.
        """
        values = dict(values or {})
        fields = set(cls.keys())
        unknown = sorted(set(values) - fields)
        if unknown:
            raise ValueError(f"{where}: unknown option(s) {', '.join(unknown)} for {cls.__name__}; "
                             f"known: {', '.join(sorted(fields))}")
        defaults = cls()
        out = {}
        for k, v in values.items():
            default = getattr(defaults, k)
            if isinstance(default, bool):
                if not isinstance(v, bool):
                    raise ValueError(f"{where}: option {k} must be true or false, got {v!r}")
            elif isinstance(default, (int, float)):
                if isinstance(v, bool) or not isinstance(v, (int, float)):
                    raise ValueError(f"{where}: option {k} must be a number, got {v!r}")
                v = type(default)(v) if isinstance(default, float) or float(v).is_integer() else v
            elif isinstance(default, str) and not isinstance(v, str):
                raise ValueError(f"{where}: option {k} must be a string, got {v!r}")
            out[k] = v
        return cls(**out).validate()


def choice(opt: Options, name: str, allowed) -> list[str]:
    """``[problem]`` when option ``name`` of ``opt`` is not one of ``allowed``, else []."""
    value = getattr(opt, name)
    if value not in allowed:
        return [f"{name} = {value!r} (one of {', '.join(map(str, allowed))})"]
    return []


def at_least(opt: Options, lowest, *names) -> list[str]:
    """Problems for the options ``names`` of ``opt`` that are below ``lowest``."""
    return [f"{k} = {getattr(opt, k)} (must be >= {lowest})" for k in names
            if not getattr(opt, k) >= lowest]


def positive(opt: Options, *names) -> list[str]:
    """Problems for the options ``names`` of ``opt`` that are not > 0."""
    return [f"{k} = {getattr(opt, k)} (must be > 0)" for k in names if not getattr(opt, k) > 0]


def within(opt: Options, name: str, lo: float, hi: float, *, open_lo=False,
           open_hi=False) -> list[str]:
    """Problem when option ``name`` is outside ``[lo, hi]`` (ends open when asked)."""
    v = getattr(opt, name)
    ok = (v > lo if open_lo else v >= lo) and (v < hi if open_hi else v <= hi)
    if ok:
        return []
    return [f"{name} = {v} (must be in {'(' if open_lo else '['}{lo}, {hi}{')' if open_hi else ']'})"]


def read_toml(path, what: str = "file") -> dict:
    """The TOML document in ``path`` (a ``--config`` table, a batch manifest).

    Raises
    ------
    ValueError naming the file: it does not exist (``what`` says what it should have been) or
    is not valid TOML.
    """
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such {what}")
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
