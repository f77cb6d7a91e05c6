"""What a cache's key holds of the package's own code: the files a result's code can run (the
import closure of some modules, read from their source) and a digest of them.

A cached result (a track, :mod:`facetransfer.track.cache`; the default model,
:mod:`facetransfer.default_model`; an ICT data set, :mod:`facetransfer.datasets.ict`; a render,
:mod:`facetransfer.render_cache`) is taken again only while the code that made it is the same.
Which files that code is, is read from the modules themselves (:func:`import_closure`), so that
no hand list of files rots as modules are added or split: a module reaches

* every module of the package that its ``import`` and ``from ... import`` statements name,
  anywhere in its body (a function's own lazy import too), and the packages above each, whose
  ``__init__`` Python runs first;
* for ``from P import N``, the submodule ``P.N`` where there is one;
* every module a string names in full (``"facetransfer.render.raster"``:
  :func:`importlib.import_module`'s);
* from a package's ``__init__``, every submodule a string names (its lazy names' table:
  :func:`facetransfer.lazy.lazy_names`, ``facetransfer.track``'s ``_LAZY``).

A module reached that the result's code does not run costs a new key for nothing, never a stale
result. The package's data files a key holds are those (under ``data/``) whose name a module of
the closure holds as a string (:func:`closure_files`).

A Python file is digested by its code alone (:func:`_code_of`: no docstrings, comments or
layout), each version parsed once (:data:`CODE_MEMO`, in the user cache, holds its digest and
the names it imports, by its bytes' sha256).
"""

from __future__ import annotations

import ast
import contextlib
import functools
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Iterable

__all__ = ["PACKAGE", "PACKAGE_ROOT", "CODE_MEMO", "MEMO_LIMIT", "code_digest",
           "closure_digest", "import_closure", "closure_files", "library_versions"]

#: The package's name and its folder.
PACKAGE, PACKAGE_ROOT = __name__.rpartition(".")[0], Path(__file__).resolve().parent
#: The memo in the user cache: a Python file's bytes' sha256 -> its code's digest
#: (:func:`_code_hash`), and ``imports:MODULE:sha256`` -> the names it imports
#: (:func:`_references`), so that a version of a file is parsed once, not at every command (the
#: track's fingerprint 0.46 CPU-s with the parses, 0.11 without); at most :data:`MEMO_LIMIT`.
CODE_MEMO, MEMO_LIMIT = "code-digests.json", 4096
#: A string that may name a module or a data file (the others are not kept in the memo).
_NAME = re.compile(r"^[A-Za-z_][\w.\-]{0,99}$")


def code_digest(root: Path, files, versions: str, *, code_only: bool = False) -> str:
    """A digest of ``files`` (their paths under ``root`` and contents; a missing one counts
    as empty) and of ``versions`` (the libraries' versions, as the caller names them).
    ``code_only``: a Python file's code alone (:func:`_code_of`: its docstrings, comments and
    layout left out), so that a reworded docstring keeps every cached entry."""
    h = hashlib.sha256()
    with _Memo() if code_only else contextlib.nullcontext({}) as memo:
        for f in files:
            h.update(str(Path(f).relative_to(root)).encode())
            data = f.read_bytes() if f.is_file() else b""
            h.update(_code_hash(data, memo).encode() if code_only and f.suffix == ".py"
                     else data)
    h.update(versions.encode())
    return h.hexdigest()[:16]


@functools.lru_cache(maxsize=None)
def library_versions(*names: str) -> str:
    """``"name=version ..."`` of the installed distributions ``names`` (``absent`` for one
    not installed), read from their metadata without importing them."""
    from importlib import metadata

    def version(name):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "absent"

    return " ".join(f"{n}={version(n)}" for n in names)


def _modules(root: Path) -> dict[str, str]:
    """Every module of the package in ``root``: its dotted name -> its file (a package's
    ``__init__.py``). (:func:`os.walk` and strings: ``Path.rglob`` took 14 ms of the 30.)"""
    out = {}
    for folder, subs, names in os.walk(root):
        subs[:] = [d for d in subs if d != "__pycache__"]
        rel = os.path.relpath(folder, root)
        parts = [PACKAGE] if rel == "." else [PACKAGE, *rel.split(os.sep)]
        for name in names:
            if name.endswith(".py"):
                stem = name[:-3]
                dotted = ".".join(parts if stem == "__init__" else [*parts, stem])
                out[dotted] = os.path.join(folder, name)
    return out


def import_closure(starts: Iterable[str], *, root: Path = PACKAGE_ROOT) -> dict[str, Path]:
    """The modules of the package (in ``root``) that the modules ``starts`` (dotted names) can
    run, themselves included: the module docstring's rule, transitively.

    Parameters
    ----------
    starts : iterable of str
        Modules of the package, e.g. ``"facetransfer.track.capture"``.
    root : Path
        The package's folder (a copy of it, in tests).

    Returns
    -------
    dict of str to Path
        Dotted name -> file, sorted by name.

    Raises
    ------
    ValueError
        A start that is not a module of the package.
    """
    with _Memo() as memo:
        return {m: entry[0] for m, entry in _closure(starts, root, memo).items()}


def closure_files(starts: Iterable[str], *, root: Path = PACKAGE_ROOT) -> list[Path]:
    """The files a key of the code of ``starts`` digests (:func:`closure_digest`): their
    :func:`import_closure`'s files and the package's data files (under ``root / "data"``)
    whose names its modules hold as strings (``"mediapipe_ibug.json"``), sorted by path."""
    with _Memo() as memo:
        return [entry[0] for entry in _closure_contents(starts, root, memo)]


def closure_digest(starts: Iterable[str], versions: str, *, root: Path = PACKAGE_ROOT) -> str:
    """:func:`code_digest` (``code_only``) of :func:`closure_files` ``(starts)`` and
    ``versions``, each file read once."""
    h = hashlib.sha256()
    with _Memo() as memo:
        for path, data, raw in _closure_contents(starts, root, memo):
            h.update(str(path.relative_to(root)).encode())
            h.update(_code_hash(data, memo, raw).encode() if path.suffix == ".py" else data)
    h.update(versions.encode())
    return h.hexdigest()[:16]


def _closure(starts: Iterable[str], root: Path, memo: dict) -> dict[str, tuple]:
    """:func:`import_closure` ``(starts)``: dotted name -> (file, its bytes, their sha256,
    what it names (:func:`_references`)), sorted by name."""
    modules = _modules(root)
    todo = list(starts)
    if unknown := [m for m in todo if m not in modules]:
        raise ValueError(f"not modules of {PACKAGE} in {root}: {', '.join(unknown)}")
    seen: dict[str, tuple] = {}
    owners: dict[str, str | None] = {}
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        with open(modules[m], "rb") as fh:
            data = fh.read()
        raw = hashlib.sha256(data).hexdigest()
        names = _references(m, modules[m].endswith("__init__.py"), raw, data, memo)
        seen[m] = (Path(modules[m]), data, raw, names)
        for n in names:
            if n not in owners:
                owners[n] = _owner(n, modules)
        reached = {owners[n] for n in names} | _parents(m, modules)
        todo.extend(r for r in reached if r and r not in seen)
    return dict(sorted(seen.items()))


def _closure_contents(starts: Iterable[str], root: Path, memo: dict) -> list[tuple]:
    """(file, its bytes, their sha256) of :func:`closure_files` ``(starts)``, sorted by
    path."""
    closure = _closure(starts, root, memo)
    folder = root / "data"
    data = {n: folder / n for n in os.listdir(folder) if (folder / n).is_file()} \
        if folder.is_dir() else {}
    named = {data[n] for *_, names in closure.values() for n in names if n in data}
    out = [entry[:3] for entry in closure.values()]
    out += [(p, content, None) for p in named for content in [p.read_bytes()]]
    return sorted(out, key=lambda entry: str(entry[0]))


def _owner(name: str, modules: dict[str, str]) -> str | None:
    """The module that ``name`` (a module, or a name inside one) lives in; None outside the
    package."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def _parents(module: str, modules: dict[str, str]) -> set[str]:
    """The packages above ``module``, whose ``__init__`` Python runs before it."""
    parts = module.split(".")
    return {p for i in range(1, len(parts)) if (p := ".".join(parts[:i])) in modules}


def _references(module: str, is_package: bool, raw: str, data: bytes, memo: dict
                 ) -> list[str]:
    """What ``module`` (its file's bytes ``data``, whose sha256 is ``raw``; ``is_package``: an
    ``__init__``) names that may be a module of the package or a data file
    (:func:`_read_references`), from ``memo`` where this version of the file is in it."""
    key = f"imports:{module}:{raw}"
    if key not in memo:
        memo[key] = _read_references(module, is_package, data)
    return memo[key]


def _read_references(module: str, is_package: bool, source: bytes) -> list[str]:
    """The dotted names ``module``'s source imports (relative ones made absolute, and
    ``P.N`` for each ``from P import N``) and its strings with a dot (a module named in full,
    a data file's name); from a package's ``__init__`` (``is_package``), ``module.S`` for every
    string ``S`` in it too. A file that does not parse names nothing."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return []
    base = module.split(".") if is_package else module.split(".")[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            where = ".".join(base[:len(base) - node.level + 1] + [node.module or ""]) \
                if node.level else (node.module or "")
            where = where.rstrip(".")
            out.update([where, *(f"{where}.{a.name}" for a in node.names)])
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str)
              and _NAME.match(node.value)):
            if "." in node.value:
                out.add(node.value)
            if is_package:
                out.add(f"{module}.{node.value}")
    return sorted(out)


def _code_hash(data: bytes, memo: dict, raw: str | None = None) -> str:
    """The sha256 of :func:`_code_of` ``(data)``, looked up in (or added to) ``memo`` by the
    sha256 of ``data`` itself (``raw``, where the caller has it)."""
    raw = hashlib.sha256(data).hexdigest() if raw is None else raw
    if raw not in memo:
        memo[raw] = hashlib.sha256(_code_of(data)).hexdigest()
    return memo[raw]


class _Memo:
    """:data:`CODE_MEMO` for a ``with`` block: its entries read as it begins, written back as
    it ends where the block added some."""

    def __enter__(self) -> dict:
        self.memo = _load_memo()
        self.known = len(self.memo)
        return self.memo

    def __exit__(self, *exc) -> None:
        if exc[0] is None and len(self.memo) != self.known:
            _save_memo(self.memo)


#: :data:`CODE_MEMO` as this process last read or wrote it: (its path, size and modification
#: time) and its entries, so that the keys one command computes (the track cache's, the
#: default model's) read it once.
_READ: dict = {}


def _memo_identity(path: Path) -> tuple | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return (str(path), st.st_size, st.st_mtime_ns)


def _load_memo() -> dict:
    """:data:`CODE_MEMO`'s entries (a copy); none where it is missing or unreadable."""
    from .assets import cache_dir

    path = cache_dir() / CODE_MEMO
    ident = _memo_identity(path)
    if ident is not None and _READ.get("identity") == ident:
        return dict(_READ["memo"])
    try:
        memo = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    memo = memo if isinstance(memo, dict) and len(memo) <= MEMO_LIMIT else {}
    _READ.update(identity=ident, memo=dict(memo))
    return memo


def _save_memo(memo: dict) -> None:
    """Write :data:`CODE_MEMO` atomically (two commands at once: the later's is kept, either
    right); a cache that cannot be written (an :class:`~facetransfer.errors.OutputError`
    too) is left as it is."""
    from .assets import cache_dir
    from .io.atomic import write_text_atomic

    path = cache_dir() / CODE_MEMO
    try:
        write_text_atomic(path, json.dumps(memo))
    except (OSError, ValueError):
        return
    _READ.update(identity=_memo_identity(path), memo=dict(memo))


def _code_of(source: bytes) -> bytes:
    """A Python file's syntax tree without its docstrings (``ast.dump``: no comments, no line
    numbers), or the file itself where it does not parse."""
    try:
        tree = ast.parse(source)
    except (SyntaxError, ValueError):
        return source
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()
