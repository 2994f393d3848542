"""rcl's C functions the compiled fast path calls, looked up in the libraries rclpy has loaded
(ctypes; no rclpy import), and the serialized message it publishes from."""

from __future__ import annotations

import ctypes
import functools
from typing import Any

import numpy as np

__all__ = ['Allocator', 'ErrorString', 'take_api', 'publish_api', 'serialized_message']


class Allocator(ctypes.Structure):
    _fields_ = [(name, ctypes.c_void_p)       # rcutils_allocator_t: four functions, a state
                for name in ('allocate', 'deallocate', 'reallocate', 'zero_allocate', 'state')]


@functools.cache
def take_api() -> Any:
    """rcl's functions for :meth:`.sample.CompiledSample.take_from` from the libraries rclpy has
    loaded (a namespace), or the reason they are not available (a str)."""
    try:
        rcl = ctypes.CDLL('librcl.so')
        rcutils = ctypes.CDLL('librcutils.so')
        api = type('RclTake', (), {})()

        def bind(lib: Any, name: str, *args: Any) -> Any:
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = ctypes.c_int32, list(args)
            return fn

        vp, size = ctypes.c_void_p, ctypes.c_size_t
        api.addresses = [ctypes.cast(getattr(rcl, name), vp).value for name in (
            'rcl_take_serialized_message', 'rcl_wait_set_clear',
            'rcl_wait_set_add_subscription', 'rcl_wait')]
        api.allocator = rcutils.rcutils_get_default_allocator
        api.allocator.argtypes, api.allocator.restype = [], Allocator
        api.wait_set_init = bind(rcl, 'rcl_wait_set_init', vp, size, size, size, size, size,
                                 size, vp, Allocator)
        api.wait_set_fini = bind(rcl, 'rcl_wait_set_fini', vp)
        api.array_init = bind(rcutils, 'rcutils_uint8_array_init', vp, size, vp)
        api.array_fini = bind(rcutils, 'rcutils_uint8_array_fini', vp)
        api.set_listener = bind(rcl, 'rcl_subscription_set_on_new_message_callback', vp, vp,
                                vp)
    except (OSError, AttributeError) as exc:
        return f'rcl is not loadable here ({exc})'
    return api


class ErrorString(ctypes.Structure):
    _fields_ = [('str', ctypes.c_char * 1024)]      # rcutils_error_string_t


@functools.cache
def publish_api() -> Any:
    """(rcl_publish_serialized_message's address, a function returning rcl's error text and
    clearing it) from the rcl and rcutils libraries rclpy has loaded, or the reason they are
    not available (a str)."""
    try:
        rcl = ctypes.CDLL('librcl.so')
        rcutils = ctypes.CDLL('librcutils.so')
        publish = ctypes.cast(rcl.rcl_publish_serialized_message, ctypes.c_void_p).value
        get = rcutils.rcutils_get_error_string
        get.argtypes, get.restype = [], ErrorString
        reset = rcutils.rcutils_reset_error
        reset.argtypes, reset.restype = [], None
    except (OSError, AttributeError) as exc:
        return f'rcl is not loadable here ({exc})'

    def take_error() -> str:
        text = get().str.decode(errors='replace')
        reset()
        return text

    return publish, take_error


def serialized_message(address: int, length: int) -> np.ndarray:
    """An rcl_serialized_message_t for the ``length`` bytes at ``address``: buffer,
    buffer_length, buffer_capacity, then an allocator that rcl does not use to publish (four
    functions and a state: zeros)."""
    message = np.zeros(8, dtype=np.int64)
    message[:3] = (address, length, length)
    return message
