"""GLSL source lookup (with ``#include``) and a program cache keyed on (files, defines).

Shaders are files in the package ``gltrack.shaders`` (the repository's top-level ``shaders/``).
Extra search folders come first: the ``search_path`` argument, then ``GLTRACK_SHADER_PATH``
(``os.pathsep``-separated), so a user can override or add shaders without touching the package.
"""
from __future__ import annotations

import os
import re
from importlib import resources
from pathlib import Path

import moderngl

_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$')


class ShaderError(RuntimeError):
    """A shader file is missing or failed to compile/link; the message carries the GLSL log."""


def _search_dirs(search_path=()) -> list[Path]:
    dirs = [Path(p) for p in search_path]
    env = os.environ.get("GLTRACK_SHADER_PATH", "")
    dirs += [Path(p) for p in env.split(os.pathsep) if p]
    dirs.append(Path(str(resources.files("gltrack.shaders"))))
    return dirs


def find_shader(name: str, search_path=()) -> Path:
    """Return the path of shader file ``name`` (absolute paths are used as they are)."""
    p = Path(name)
    if p.is_absolute() or p.exists() and p.suffix in {".vert", ".frag", ".comp", ".glsl"}:
        if p.is_file():
            return p
        raise ShaderError(f"shader file not found: {name}")
    tried = []
    for d in _search_dirs(search_path):
        cand = d / name
        tried.append(str(d))
        if cand.is_file():
            return cand
    raise ShaderError(f"shader file {name!r} not found in: {', '.join(tried)}")


def load_source(name: str, defines: dict | None = None, search_path=(), aliases=None) -> str:
    """Read a shader, expand ``#include "file"`` lines and insert ``#define``s after ``#version``.

    Included files are marked with ``#line`` directives so compiler logs point into the right
    file (numbered in the order listed in the returned source's comment header). ``aliases`` maps
    an include name to the file actually read (how a user's custom cost replaces a stock include).
    """
    aliases = dict(aliases or {})
    files: list[str] = []

    def expand(fname: str, depth: int) -> list[str]:
        if depth > 8:
            raise ShaderError(f"#include nesting too deep at {fname}")
        path = find_shader(aliases.get(fname, fname), search_path)
        files.append(str(path))
        idx = len(files) - 1
        out = []
        for lineno, line in enumerate(path.read_text().splitlines(), start=1):
            m = _INCLUDE.match(line)
            if m:
                out += expand(m.group(1), depth + 1)
                out.append(f"#line {lineno + 1} {idx}")
            else:
                out.append(line)
        return out

    lines = expand(name, 0)
    if not lines or not lines[0].startswith("#version"):
        raise ShaderError(f"{files[0]}: first line must be a #version directive")
    head = [lines[0]] + [f"// file {i}: {f}" for i, f in enumerate(files)]
    for key, val in (defines or {}).items():
        head.append(f"#define {key} {val}")
    head.append("#line 2 0")
    return "\n".join(head + lines[1:]) + "\n"


class ProgramCache:
    """Compile each (stage files, defines) combination once per context."""

    def __init__(self, ctx: moderngl.Context, search_path=()):
        self.ctx = ctx
        self.search_path = tuple(search_path)
        self._cache: dict = {}

    def get(self, *, vertex=None, fragment=None, compute=None, defines=None,
            varyings=None, aliases=None):
        """Return a compiled ``moderngl.Program`` (or ``ComputeShader`` if ``compute``)."""
        key = (vertex, fragment, compute, tuple(sorted((defines or {}).items())),
               tuple(sorted((aliases or {}).items())))
        if key in self._cache:
            return self._cache[key]
        try:
            if compute is not None:
                src = load_source(compute, defines, self.search_path, aliases)
                prog = self.ctx.compute_shader(src)
            else:
                vs = load_source(vertex, defines, self.search_path, aliases)
                fs = load_source(fragment, defines, self.search_path, aliases) if fragment else None
                prog = self.ctx.program(vertex_shader=vs, fragment_shader=fs, varyings=varyings or ())
        except moderngl.Error as exc:
            names = ", ".join(n for n in (vertex, fragment, compute) if n)
            raise ShaderError(f"GLSL compile/link failed for {names}:\n{exc}") from None
        self._cache[key] = prog
        return prog

    def release(self):
        for prog in self._cache.values():
            prog.release()
        self._cache.clear()
