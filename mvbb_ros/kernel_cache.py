"""
Fresh numba caches across files: a kernel's cache goes stale when a module it calls into changes.

numba compiles a kernel's jitted callees into the kernel's own machine code, but when it loads
the cache it checks only the kernel's own source file. A kernel of ``fit.py`` that calls into
``hull.py`` would keep running the old hull code after an edit of ``hull.py``. For this
package's kernels numba's cache locator is therefore wrapped (:class:`PackageCacheLocator`): the
cache lives where numba would put it (``NUMBA_CACHE_DIR``, the module's ``__pycache__``, or the
user's cache directory when the package folder is read-only), and its source stamp also covers
every module of the package that imports numba and that the kernel's module imports, directly or
through other modules of the package (:func:`dependency_digest`). So an edit of ``hull.py``
recompiles the kernels of ``hull.py``, ``search.py``, ``fit.py`` and of the modules that import
them, and nothing else.

A cache that cannot be used never stops a start: a torn or unreadable cache entry (a power cut
right after a compile leaves one) is discarded and the kernel compiled again, and a cache folder
that cannot be written (a read-only install and a read-only home) means the kernels are compiled
in memory for the run; each says so in one :class:`KernelCacheWarning`. A read-only install that
ships a cache in its ``__pycache__`` loads it from there wherever it is valid.

The packages that hold kernels (``mvbb_ros/geometry/__init__.py`` and
``mvbb_ros/pipeline/__init__.py``) import this module before any of their modules, so the
wrapper is in place before any kernel of the package is defined (numba picks a kernel's locator
when it is decorated); :mod:`mvbb_ros.kernels` lists and warms the kernels.
"""

from __future__ import annotations

import errno
import functools
import hashlib
import os
from pathlib import Path
import re
import sys
from types import FunctionType
from typing import Any
import warnings

from numba.core import caching, config

#: The package's folder: kernels defined under it get :class:`PackageCacheLocator`.
PACKAGE_ROOT = Path(__file__).resolve().parent

#: ``from mvbb_ros.x import a, b`` (names possibly in parentheses over lines) and
#: ``import mvbb_ros.x``, anywhere in a line (imports inside functions count too).
_FROM_IMPORT = re.compile(r'^\s*from\s+(mvbb_ros[\w.]*)\s+import\s+(\([^)]*\)|[^\n#]*)', re.M)
_PLAIN_IMPORT = re.compile(r'^\s*import\s+(mvbb_ros[\w.]*)', re.M)


def _module_file(name: str) -> Path | None:
    """Return the source file of package module `name`, or None when it is no module."""
    parts = name.split('.')[1:]
    base = PACKAGE_ROOT.joinpath(*parts)
    for path in (base.with_suffix('.py'), base / '__init__.py'):
        if path.is_file():
            return path
    return None


@functools.cache
def _imported_files(path: Path) -> tuple[Path, ...]:
    """Return the package's source files that the module at `path` imports (one level)."""
    text = path.read_text(encoding='utf-8')
    names = set(_PLAIN_IMPORT.findall(text))
    for module, imported in _FROM_IMPORT.findall(text):
        names.add(module)
        # `from mvbb_ros.geometry.boxfit import hull as hull_module`: the names may be modules.
        for item in imported.strip('()').split(','):
            word = item.split(' as ')[0].strip()
            if word.isidentifier():
                names.add(f'{module}.{word}')
    files = {_module_file(name) for name in names}
    return tuple(sorted(file for file in files if file is not None and file != path))


@functools.cache
def dependency_digest(path: Path) -> str:
    """
    Return a digest of the kernel modules that the module at `path` can call into.

    The module itself and every module of the package it imports, directly or through other
    modules of the package, whose source imports numba (only those can hold jitted callees):
    SHA-256 over their package-relative names and contents.

    :param path: a source file of the package.
    :return: the hex digest.
    """
    seen = {path}
    waiting = [path]
    while waiting:
        for file in _imported_files(waiting.pop()):
            if file not in seen:
                seen.add(file)
                waiting.append(file)
    digest = hashlib.sha256()
    for file in sorted(seen):
        text = file.read_bytes()
        if file == path or b'import numba' in text:
            digest.update(str(file.relative_to(PACKAGE_ROOT)).encode() + b'\0' + text + b'\0')
    return digest.hexdigest()


class KernelCacheWarning(RuntimeWarning):
    """A kernel cache entry could not be used or written: the kernel was compiled instead."""


#: What has been warned about in this process (one warning per folder and kind of trouble).
_WARNED: set[tuple[str, str]] = set()


def _warn_once(kind: str, folder: str, message: str) -> None:
    """Warn with a :class:`KernelCacheWarning` once per process for `kind` and `folder`."""
    if (kind, folder) not in _WARNED:
        _WARNED.add((kind, folder))
        warnings.warn(message, KernelCacheWarning, stacklevel=3)


def _ships_cache(py_func: FunctionType, py_file: str) -> bool:
    """Whether the module's own ``__pycache__`` holds an index of `py_func`'s compiled code."""
    folder = Path(py_file).parent / '__pycache__'
    qualname = py_func.__qualname__.replace('<', '').replace('>', '')
    line = py_func.__code__.co_firstlineno
    pattern = (
        f'{Path(py_file).stem}.{qualname}-{line}.py{sys.version_info[0]}{sys.version_info[1]}*.nbi'
    )
    return folder.is_dir() and any(folder.glob(pattern))


class PackageCacheLocator(caching._CacheLocator):
    """
    numba's own cache locator for a kernel of this package, with a stamp over its callees' files.

    The cache path and the disambiguator are those of the locator numba would have chosen (its
    ``NUMBA_CACHE_DIR``, the module's ``__pycache__`` or the user-wide cache directory); the source
    stamp adds :func:`dependency_digest` to numba's stamp, so a cached kernel is recompiled when
    any kernel module it can call into has changed.
    """

    #: Marks the wrapper (a module run twice, as ``__main__`` too, must not install two).
    wraps_numba_locator = True

    def __init__(self, inner: Any, py_file: str, *, read_only: bool = False) -> None:
        self._inner = inner
        # numba's warnings about uncachable functions name the file through this attribute.
        self._py_file = py_file
        #: Load from the folder but never write there (a read-only install's shipped cache).
        self.read_only = read_only

    def ensure_cache_path(self) -> None:
        """Make sure the cache folder exists and is writable (numba's check)."""
        if self.read_only:
            raise OSError(
                errno.EROFS, 'the kernel cache folder is read-only', self.get_cache_path()
            )
        self._inner.ensure_cache_path()

    def get_cache_path(self) -> str:
        """Return the folder numba's own locator chose."""
        return str(self._inner.get_cache_path())

    def get_source_stamp(self) -> tuple[Any, str]:
        """Return numba's stamp of the kernel's file and the digest of the files it calls into."""
        return self._inner.get_source_stamp(), dependency_digest(Path(self._py_file).resolve())

    def get_disambiguator(self) -> str:
        """Return numba's disambiguator (the function's line number)."""
        return str(self._inner.get_disambiguator())

    @classmethod
    def from_function(cls, py_func: FunctionType, py_file: str) -> PackageCacheLocator | None:
        """Wrap the locator numba would choose for a function of this package; None otherwise."""
        try:
            Path(py_file).resolve().relative_to(PACKAGE_ROOT)
        except (OSError, ValueError):
            return None
        others: list[Any] = [
            other
            for other in caching.CacheImpl._locator_classes
            if not getattr(other, 'wraps_numba_locator', False)
        ]
        # numba's locator for the module's own __pycache__ (named with or without an underscore).
        in_tree: Any = next(
            (other for other in others if other.__name__.endswith('InTreeCacheLocator')), None
        )
        shipped = (
            in_tree is not None
            and not getattr(config, 'CACHE_DIR', '')
            and not os.access(Path(py_file).parent, os.W_OK)
            and _ships_cache(py_func, py_file)
        )
        if shipped:
            return cls(in_tree(py_func, py_file), py_file, read_only=True)
        for other in others:
            inner = other.from_function(py_func, py_file)
            if inner is not None:
                return cls(inner, py_file)
        if in_tree is not None:  # nowhere writable: compile in memory, never fail the import
            return cls(in_tree(py_func, py_file), py_file, read_only=True)
        return None


def _probe() -> None:
    """Stand-in function for asking where a module's kernels are cached."""


def cache_folder(module_file: Path) -> Path | None:
    """Return the folder that holds (or would hold) the kernel caches of a package module."""
    locator = PackageCacheLocator.from_function(_probe, str(module_file))  # type: ignore[arg-type]
    return None if locator is None else Path(locator.get_cache_path())


def _is_ours(cache: Any) -> bool:
    """Whether a numba cache belongs to a kernel of this package."""
    return isinstance(getattr(cache._impl, 'locator', None), PackageCacheLocator)


def _discard(cache: Any) -> None:
    """Remove a cache's index file, so the next save starts a fresh one (best effort)."""
    try:
        os.unlink(cache._cache_file._index_path)
    except OSError:
        pass


def _install_healing() -> None:
    """Make loading and saving this package's kernel caches survive bad or read-only files."""
    load, save = caching.Cache.load_overload, caching.Cache.save_overload
    if getattr(load, 'heals_package_caches', False):
        return

    def load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        if not _is_ours(self):
            return load(self, sig, target_context)
        try:
            return load(self, sig, target_context)
        except Exception as error:  # a cache is only a shortcut: whatever broke it, compile
            _discard(self)
            _warn_once(
                'unreadable',
                str(self._cache_path),
                f'kernel cache in {self._cache_path} could not be read ({type(error).__name__}: '
                f'{error}); discarded, compiling again',
            )
            return None

    def save_overload(self: Any, sig: Any, data: Any) -> None:
        if not _is_ours(self):
            save(self, sig, data)
            return
        try:
            save(self, sig, data)
        except OSError as error:
            _warn_once(
                'unwritable',
                str(self._cache_path),
                f'kernel cache in {self._cache_path} cannot be written ({error.strerror}); '
                'kernels are compiled in memory for this run',
            )

    load_overload.heals_package_caches = True  # type: ignore[attr-defined]
    caching.Cache.load_overload = load_overload  # type: ignore[method-assign]
    caching.Cache.save_overload = save_overload  # type: ignore[method-assign]


def _install_locator() -> None:
    """Put :class:`PackageCacheLocator` first among numba's locators (once)."""
    locators = caching.CacheImpl._locator_classes
    if not any(getattr(other, 'wraps_numba_locator', False) for other in locators):
        locators.insert(0, PackageCacheLocator)


_install_locator()
_install_healing()
