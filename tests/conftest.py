import contextlib
import dataclasses
import os

import pytest

# Keep PoCL's kernel cache inside the user's cache (or CI's) rather than a read-only HOME.
os.environ.setdefault("POCL_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "pocl"))


@pytest.fixture(scope="session")
def device():
    """One OpenCL context for the whole session, so each program compiles once."""
    import pydynrad

    return pydynrad.default_device()


@pytest.fixture
def portable_kernels(device, monkeypatch):
    """A context manager under which kernels are built as on any OpenCL CPU: vload/vstore
    instead of the aligned vector dereference PoCL's clang allows (``PDR_CLANG_VECTORS``).
    On leaving it checks that programs were built and none with that define. Skips where the
    device never takes the clang path (every kernel there is the portable one)."""
    if not device.traits.aligned_vectors:
        pytest.skip(f"{device.name} builds only the portable kernels")

    @contextlib.contextmanager
    def portable():
        built, program = [], device.program

        def recording(filename, defines=None):
            built.append(dict(defines or {}))
            return program(filename, defines)

        with monkeypatch.context() as m:
            m.setattr(device, "_traits", dataclasses.replace(device.traits, aligned_vectors=False))
            m.setattr(device, "program", recording)
            yield
        assert built and not any("PDR_CLANG_VECTORS" in d for d in built)

    return portable
