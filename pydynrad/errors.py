"""Exceptions raised by pydynrad.

Every error the library raises on purpose derives from :class:`PydynradError`; errors about
bad values (shapes, ranges, NaNs, unknown names) also derive from :class:`ValueError`, so
callers that already catch ``ValueError`` keep working.
"""

from __future__ import annotations


class PydynradError(Exception):
    """Base class of every error pydynrad raises on purpose."""


class InvalidInputError(PydynradError, ValueError):
    """An argument or an input file holds a value pydynrad cannot use."""


class SceneFileError(InvalidInputError):
    """A scene file is missing, unreadable or malformed."""


class OutOfMemoryError(PydynradError, MemoryError):
    """A requested matrix or buffer would not fit in the memory available."""


class KernelBuildError(PydynradError):
    """An OpenCL program failed to build; ``build_log`` holds the compiler's output."""

    def __init__(self, message: str, build_log: str = "") -> None:
        super().__init__(f"{message}\n{build_log}" if build_log else message)
        self.build_log = build_log


class DeviceError(PydynradError):
    """No usable OpenCL device, or the device refused a request."""


class ConvergenceError(PydynradError):
    """An iterative solve did not reach its tolerance within its iteration budget."""


class MissingExtraError(PydynradError, ImportError):
    """An optional dependency is not installed; the message names the extra that installs it.

    ``MissingExtraError("precompute_distributed", "Dask", "dask")`` reads "precompute_distributed
    needs Dask: pip install 'pydynrad[dask]'"; ``alternative`` adds a way that needs no extra
    (", or ..."). Also an :class:`ImportError`, so code that already guards an optional import
    with ``except ImportError`` keeps working. ``name`` is the module that was missing.
    """

    def __init__(self, feature: str, needs: str, extra: str, *, alternative: str = "", name: str | None = None) -> None:
        super().__init__(
            f"{feature} needs {needs}: pip install 'pydynrad[{extra}]'"
            + (f", or {alternative}" if alternative else ""),
            name=name,
        )
        self.feature = feature
        self.extra = extra
