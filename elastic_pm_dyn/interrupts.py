"""A Ctrl-C that Python swallowed still counts.

A SIGINT raises KeyboardInterrupt wherever the main thread is; when that is inside a
finalizer (``__del__``: llvmlite's run during numba's first compile), Python prints it as
"Exception ignored ... Traceback" and goes on, so a program interrupted while it starts
would start anyway (seen in CI). :func:`install` (run when the console scripts' entry module
is imported) counts every SIGINT and keeps those tracebacks quiet; until :func:`arm` (the
entry point's guard is up) a SIGINT is only counted, so one that lands between the import and
the guard (seen in CI, on a loaded machine) is not a traceback either; code that ends a start-up
asks :func:`requested`; :func:`ending` quiets every finalizer once the program ends on a Ctrl-C.
"""

from __future__ import annotations

import signal
import sys
from typing import Any

_received = 0
_armed = False  # a SIGINT raises KeyboardInterrupt (else it is only counted: no guard is up yet)
_ending = False  # the program ends on a Ctrl-C: no finalizer's error is worth a traceback then
_default_hook = sys.unraisablehook


def _on_sigint(_signum: int, _frame: object) -> None:
    global _received
    _received += 1
    if _armed:
        raise KeyboardInterrupt


def _quiet(unraisable: Any) -> None:
    if not (_ending or isinstance(unraisable.exc_value, KeyboardInterrupt)):
        _default_hook(unraisable)


def install() -> None:
    """Count SIGINTs (unless SIGINT is ignored, as in a background job) and keep a
    KeyboardInterrupt swallowed by a finalizer from printing a traceback."""
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_sigint)
    sys.unraisablehook = _quiet


def arm() -> None:
    """From now on a SIGINT raises KeyboardInterrupt; one counted before raises it here."""
    global _armed
    _armed = True
    if _received:
        raise KeyboardInterrupt


def requested() -> bool:
    """Has a SIGINT come since :func:`install` (even one a finalizer swallowed)?"""
    return _received > 0


def ending() -> None:
    """The program ends on a Ctrl-C: objects the interrupt left half-built (llvmlite's, in an
    interrupted numba compile) may fail in their finalizers at exit; print none of that."""
    global _ending
    _ending = True
    sys.unraisablehook = _quiet
