"""Build script: the package metadata lives in pyproject.toml; this file only wires the
layout of the design card (top-level ``kernels/`` shipped as ``pydynrad.kernels``) and the
native helpers in ``csrc/`` (the BVH builder, ray batches' checks, the hemicube runs' CSR, a move's segments near a sphere)."""

from setuptools import Extension, find_packages, setup

setup(
    packages=[*find_packages(include=["pydynrad", "pydynrad.*"]), "pydynrad.kernels"],
    package_dir={"pydynrad": "pydynrad", "pydynrad.kernels": "kernels"},
    package_data={"pydynrad.kernels": ["*.cl", "*.h"]},
    ext_modules=[
        Extension(
            "pydynrad._bvh",
            sources=["csrc/bvh.c"],
            extra_compile_args=["-O3", "-std=c99"],
        ),
        Extension(
            "pydynrad._raybatch",
            sources=["csrc/rays.c"],
            extra_compile_args=["-O3", "-std=c99"],
        ),
        Extension(
            "pydynrad._runs",
            sources=["csrc/runs.c"],
            extra_compile_args=["-O3", "-std=c99"],
        ),
        Extension(
            "pydynrad._segments",
            sources=["csrc/segments.c"],
            extra_compile_args=["-O3", "-std=c99"],
        ),
    ],
)
