"""The study manifest of ``gltrack batch --manifest study.toml``: datasets and their overrides.

Format (TOML)::

    [defaults]                 # optional; each key as in a [[dataset]] table
    method = "hc"
    options = { levels = 2 }   # tracker options (the method's Options class)

    [[dataset]]
    path = "takes/s01_walk"    # required; relative paths are relative to the manifest's folder
    name = "s01_walk"          # optional: the results folder DIR/<name> (default: the folder name)
    method = "hc+ep"           # optional override of --method / [defaults]
    frames = "0:300"           # optional, "A:B" or [A, B]: frames A (inclusive) to B (exclusive)
    options = { particles = 200 }  # optional, on top of --config and [defaults].options

Unknown keys and values of the wrong type are errors naming the file and the field
(``study.toml: dataset[2].frames: ...``).
"""
from __future__ import annotations

import re
from pathlib import Path

from .options import read_toml

#: the keys of a [[dataset]] table, and of [defaults] (which has no path or name)
DATASET_KEYS = ("path", "name", "method", "frames", "options")
DEFAULT_KEYS = ("method", "frames", "options")


def parse_frames_field(value, where: str):
    """``"A:B"`` or ``[A, B]`` -> (A, B) with 0 <= A < B; ValueError naming ``where``."""
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(\d+)\s*:\s*(\d+)\s*", value)
        pair = (int(m.group(1)), int(m.group(2))) if m else None
    elif (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, int) and not isinstance(v, bool) for v in value)):
        pair = (int(value[0]), int(value[1]))
    else:
        pair = None
    if pair is None or not 0 <= pair[0] < pair[1]:
        raise ValueError(f"{where}: must be \"A:B\" or [A, B] with integers 0 <= A < B, "
                         f"got {value!r}")
    return pair


def _check_table(table, keys, where: str) -> None:
    if not isinstance(table, dict):
        raise ValueError(f"{where}: must be a table, got {type(table).__name__}")
    unknown = sorted(set(table) - set(keys))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; known: "
                         f"{', '.join(keys)}")


def _entry_value(entry: dict, key: str, kind, where: str):
    value = entry.get(key)
    if value is not None and not isinstance(value, kind):
        raise ValueError(f"{where}.{key}: must be a {kind.__name__}, got {value!r}")
    return value


def load_manifest(path, methods) -> tuple[list[dict], dict]:
    """Read and check a manifest.

    Parameters
    ----------
    path : the manifest file
    methods : container of the known method names

    Returns
    -------
    (entries, defaults): entries are dicts with ``path`` (str, resolved against the manifest's
    folder), ``name`` (str or None), ``method`` (str or None), ``frames`` ((A, B) or None),
    ``options`` (dict) and ``where`` (``"FILE: dataset[i]"``, for later messages); defaults
    has ``method``, ``frames``, ``options`` (each possibly None).

    Raises
    ------
    ValueError naming the file and the field.
    """
    path = Path(path)
    doc = read_toml(path, "manifest file")
    _check_table(doc, ("defaults", "dataset"), str(path))
    defaults = doc.get("defaults", {})
    _check_table(defaults, DEFAULT_KEYS, f"{path}: defaults")
    out_defaults = {"method": None, "frames": None, "options": None}
    for key in DEFAULT_KEYS:
        if key in defaults:
            out_defaults[key] = _field(defaults, key, f"{path}: defaults", methods)
    datasets = doc.get("dataset")
    if not isinstance(datasets, list) or not datasets:
        raise ValueError(f"{path}: dataset: give at least one [[dataset]] table with a path")
    entries = []
    base = path.parent
    for i, entry in enumerate(datasets):
        where = f"{path}: dataset[{i}]"
        _check_table(entry, DATASET_KEYS, where)
        p = _entry_value(entry, "path", str, where)
        if not p:
            raise ValueError(f"{where}.path: missing (the dataset folder)")
        name = _entry_value(entry, "name", str, where)
        if name is not None and (not name or "/" in name or name in (".", "..")
                                 or name == "summary.json"):
            raise ValueError(f"{where}.name: {name!r} is not a folder name")
        rec = {"path": str(Path(p) if Path(p).is_absolute() else base / p), "name": name,
               "where": where, "method": None, "frames": None, "options": {}}
        for key in DEFAULT_KEYS:
            if key in entry:
                rec[key] = _field(entry, key, where, methods)
        entries.append(rec)
    return entries, out_defaults


def _field(table: dict, key: str, where: str, methods):
    value = table[key]
    if key == "method":
        if not isinstance(value, str) or value not in methods:
            raise ValueError(f"{where}.method: unknown method {value!r}; known: "
                             f"{', '.join(sorted(methods))}")
        return value
    if key == "frames":
        return parse_frames_field(value, f"{where}.frames")
    if not isinstance(value, dict):
        raise ValueError(f"{where}.options: must be a table of tracker options, got {value!r}")
    return dict(value)
