"""The kernels' numba decorators, with a cache keyed on every kernel module's source.

numba's cache checks only the source file of the function it caches, but a compiled kernel
holds the code of every callee it calls, from whatever module: after an edit to a callee in
another module, numba would silently load the stale machine code. Here the cache of every
function defined in a registered package directory is keyed on a hash of all the ``.py``
files in that directory, so that an edit to any of them recompiles every kernel (numba
overwrites an index whose key differs). Everything else (where the cache lives,
NUMBA_CACHE_DIR, the fallbacks for a read-only install) is numba's own.
"""

from __future__ import annotations

import functools
import hashlib
import os

from numba import njit
from numba.core import caching

#: Each registered package directory and the directories its kernels also link code from.
_PACKAGES: dict[str, tuple[str, ...]] = {}


def _package_stamp(directory: str) -> str:
    """SHA-256 of the names and contents of the ``.py`` files of the directory and of those
    it depends on (:func:`register_package`)."""
    stamps = [_directory_stamp(directory)]
    stamps += [_directory_stamp(other) for other in _PACKAGES.get(directory, ())]
    return stamps[0] if len(stamps) == 1 else hashlib.sha256("".join(stamps).encode()).hexdigest()


def _directory_stamp(directory: str) -> str:
    files = tuple(
        (name, os.stat(os.path.join(directory, name)).st_mtime_ns)
        for name in sorted(os.listdir(directory))
        if name.endswith(".py")
    )
    return _hash_files(directory, files)


@functools.cache
def _hash_files(directory: str, files: tuple[tuple[str, int], ...]) -> str:
    # (keyed on the modification times too, so that an edit within one process rehashes)
    digest = hashlib.sha256()
    for name, _ in files:
        digest.update(name.encode())
        with open(os.path.join(directory, name), "rb") as file:
            digest.update(hashlib.sha256(file.read()).digest())
    return digest.hexdigest()


class _PackageStamp:
    """Locator mixin: the source stamp is the package's, not the function's file's."""

    @classmethod
    def from_function(cls, py_func, py_file):  # type: ignore[no-untyped-def]
        if os.path.dirname(os.path.abspath(py_file)) not in _PACKAGES:
            return None
        return super().from_function(py_func, py_file)  # type: ignore[misc]

    def get_source_stamp(self) -> str:
        return _package_stamp(os.path.dirname(os.path.abspath(self._py_file)))  # type: ignore[attr-defined]


class _UserProvided(_PackageStamp, caching.UserProvidedCacheLocator):
    pass


class _InTree(_PackageStamp, caching.InTreeCacheLocator):
    pass


class _UserWide(_PackageStamp, caching.UserWideCacheLocator):
    pass


#: The locators that key a cache on its package (numba tries them before its own).
LOCATORS = (_UserProvided, _InTree, _UserWide)
caching.CacheImpl._locator_classes[:0] = [
    c for c in LOCATORS if c not in caching.CacheImpl._locator_classes
]


def register_package(directory: str, *depends: str) -> None:
    """Key the cache of every kernel defined in ``directory`` on all of its sources, and on
    those of the ``depends`` directories whose kernels it links."""
    _PACKAGES[os.path.abspath(directory)] = tuple(os.path.abspath(other) for other in depends)


register_package(os.path.dirname(__file__))

# Without numba's runtime (_nrt): the kernels allocate nothing (their arrays are in their stack
# frames, linalg.stack_empty), and arrays then carry no reference counts, whose calls (an
# atomic operation each on a live array) took 14% of a three-finger solve.
_options = dict(cache=True, nogil=True, error_model="numpy", _nrt=False)
#: A compiled kernel without a Python wrapper (called from other kernels only).
kernel = njit(**_options, no_cpython_wrapper=True)
#: Inlined into its callers: small helpers and the attempts (numba compiles every callee's
#: code again into each caller that links it, so inlining costs no more and saves a call).
inline = njit(**_options, no_cpython_wrapper=True, inline="always")
#: An entry point, callable from Python.
entry = njit(**_options)
