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


# Scenes several test files share, named for what they are: a fixture name means one scene everywhere.
@pytest.fixture(scope="session")
def closed_box_48():
    """The unit closed box, one subdivision: 48 patches, every row of F sums to 1."""
    import pydynrad

    return pydynrad.scenes.closed_box(subdivisions=1)


@pytest.fixture(scope="module")
def closed_box_48_F(closed_box_48, device):
    """F of :func:`closed_box_48` at R = 16 (a fresh CSR matrix per test module: tests may break copies)."""
    import pydynrad

    return pydynrad.form_factors(closed_box_48, resolution=16, device=device)


@pytest.fixture(scope="session")
def cornell_384():
    """The Cornell box patched to a 200 mm edge: 384 patches, millimetres, +y up."""
    import pydynrad

    return pydynrad.scenes.cornell_box(max_edge=200.0)


@pytest.fixture(scope="session")
def green_block():
    """A 100 mm cube, green: the block moved through :func:`cornell_384` (its light bleeds onto the floor)."""
    import pydynrad

    return pydynrad.scenes.block(100.0, 1, albedo=(0.1, 0.7, 0.1))
