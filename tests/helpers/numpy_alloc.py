"""Count every numpy data allocation: a PyDataMem handler (NumPy >= 1.22, NEP 49) installed through
ctypes whose malloc/calloc/realloc count and delegate to libc. Unlike a tracemalloc snapshot, which
only sees blocks still alive, this also sees temporaries that were freed again."""

from __future__ import annotations

import contextlib
import ctypes

import numpy as np

try:
    from numpy._core import _multiarray_umath as _mu
except ImportError:  # NumPy 1.x
    from numpy.core import _multiarray_umath as _mu

_SET_HANDLER, _GET_HANDLER = 304, 305  # indices in NumPy's C-API table (numpy_api.py)

_libc = ctypes.CDLL(None)
_libc.malloc.restype = ctypes.c_void_p
_libc.malloc.argtypes = [ctypes.c_size_t]
_libc.calloc.restype = ctypes.c_void_p
_libc.calloc.argtypes = [ctypes.c_size_t, ctypes.c_size_t]
_libc.realloc.restype = ctypes.c_void_p
_libc.realloc.argtypes = [ctypes.c_void_p, ctypes.c_size_t]
_libc.free.argtypes = [ctypes.c_void_p]

_MALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)
_CALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t)
_REALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)
_FREE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)


class _Allocator(ctypes.Structure):
    _fields_ = [("ctx", ctypes.c_void_p), ("malloc", _MALLOC), ("calloc", _CALLOC),
                ("realloc", _REALLOC), ("free", _FREE)]  # fmt: skip


class _Handler(ctypes.Structure):
    _fields_ = [("name", ctypes.c_char * 127), ("version", ctypes.c_uint8), ("allocator", _Allocator)]


COUNT = [0]


def _malloc(ctx, n):
    COUNT[0] += 1
    return _libc.malloc(n)


def _calloc(ctx, a, b):
    COUNT[0] += 1
    return _libc.calloc(a, b)


def _realloc(ctx, p, n):
    COUNT[0] += 1
    return _libc.realloc(p, n)


def _free(ctx, p, n):
    _libc.free(p)


# module-level for the life of the process: arrays made under the handler free through it
_CALLBACKS = (_MALLOC(_malloc), _CALLOC(_calloc), _REALLOC(_realloc), _FREE(_free))
_HANDLER = _Handler(b"counting_allocator", 1, _Allocator(None, *_CALLBACKS))
_get_ptr = ctypes.pythonapi.PyCapsule_GetPointer
_get_ptr.restype = ctypes.c_void_p
_get_ptr.argtypes = [ctypes.py_object, ctypes.c_char_p]
_new_capsule = ctypes.pythonapi.PyCapsule_New
_new_capsule.restype = ctypes.py_object
_new_capsule.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
_NAME = ctypes.create_string_buffer(b"mem_handler")  # the capsule keeps a pointer to its name
_table = ctypes.cast(_get_ptr(_mu._ARRAY_API, None), ctypes.POINTER(ctypes.c_void_p))
_set_handler = ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.py_object)(_table[_SET_HANDLER])
_CAPSULE = _new_capsule(ctypes.addressof(_HANDLER), ctypes.addressof(_NAME), None)


@contextlib.contextmanager
def counting():
    """Within the block every numpy data allocation increments COUNT[0]."""
    old = _set_handler(_CAPSULE)
    try:
        assert np._core.multiarray.get_handler_name() == "counting_allocator"
        yield COUNT
    finally:
        _set_handler(old)


def count_allocations(fn) -> int:
    with counting() as c:
        start = c[0]
        fn()
        return c[0] - start
