"""Storage precisions of the matrices (fp16, fp32, fp64) and the types their products compute in.

A storage name is what users pick (``storage="fp16"``); the host and the device layers both
read its element type and its compute type from here.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError

#: Element type in device memory per storage name.
STORAGE_DTYPES: dict[str, np.dtype] = {
    "fp16": np.dtype(np.float16),
    "fp32": np.dtype(np.float32),
    "fp64": np.dtype(np.float64),
}


def storage_dtype(storage: str) -> np.dtype:
    """The numpy element type of a storage name; InvalidInputError naming the allowed ones."""
    try:
        return STORAGE_DTYPES[storage]
    except (KeyError, TypeError):
        raise InvalidInputError(f"unknown storage {storage!r}; allowed: {', '.join(STORAGE_DTYPES)}") from None


def compute_dtype(storage: str) -> np.dtype:
    """The type kernels compute in and vectors are passed as: float64 for fp64 storage, else float32."""
    return np.dtype(np.float64 if storage_dtype(storage) == np.float64 else np.float32)
