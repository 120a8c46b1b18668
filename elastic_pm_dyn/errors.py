"""Exceptions for user mistakes and physical impossibilities.

Every error carries a one-line message that says what is wrong and where, so the
command line can print it without a traceback.
"""

from __future__ import annotations


class ElasticPmDynError(Exception):
    """Base class: a clear, user-facing error."""


class ModelError(ElasticPmDynError):
    """A model file is malformed or describes an impossible machine.

    The message names the file, the key path and, where known, the line.
    """

    def __init__(self, file: str, key_path: str, message: str, line: int | None = None):
        self.file = file
        self.key_path = key_path
        self.line = line
        self.message = message
        where = f"{file}:{line}" if line is not None else file
        super().__init__(f"{where}: {key_path or '<root>'}: {message}")


class InputError(ElasticPmDynError):
    """Bad run input: torque tables, command-line values, states."""


class OutputError(ElasticPmDynError):
    """An output could not be written (disk full, file too large, no permission); the
    message names the user's path, never a temporary one."""


class AssemblyError(ElasticPmDynError):
    """The closure cannot be satisfied (unreachable pose or wrong assembly mode)."""


class SingularConfigurationError(ElasticPmDynError):
    """The mechanism reached a configuration where the formulation breaks down.

    ``time`` and ``residual`` say when and how badly; a simulator attaches the partial
    result it had up to that moment as ``partial``.
    """

    def __init__(self, message: str, time: float | None = None, residual: float | None = None):
        self.time = time
        self.residual = residual
        self.partial = None
        super().__init__(message)


class DivergedStateError(SingularConfigurationError):
    """The integration blew up (a step too large for the motion, or a torque too high):
    not a singular configuration, though handled as one (the run stops, the partial result
    is kept, a plant keeps its last good state)."""


class OnePassDivergenceError(SingularConfigurationError):
    """The paper's one-pass SCDD (``scdd_one_pass``) diverges at this pose: its convergence
    factor (``factor``, the spectral radius of its iteration, dynamics/one_pass.py) is >= 1.
    Handled as a singular configuration: the run stops, the partial result is kept."""

    def __init__(self, message: str, factor: float, time: float | None = None, residual: float | None = None):
        self.factor = factor
        super().__init__(message, time, residual)


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C during a run: still a KeyboardInterrupt (the program stops), but it carries
    the samples computed so far as ``partial`` and the time of the last one as ``time``."""

    def __init__(self, message: str, time: float, partial: object):
        self.time = time
        self.partial = partial
        super().__init__(message)
