import os

import pytest

# Keep PoCL's kernel cache inside the user's cache (or CI's) rather than a read-only HOME.
os.environ.setdefault("POCL_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "pocl"))


@pytest.fixture(scope="session")
def device():
    """One OpenCL context for the whole session, so each program compiles once."""
    import pydynrad

    return pydynrad.default_device()
