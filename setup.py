"""Build script: the package metadata lives in pyproject.toml; this file only wires the
layout of the design card (top-level ``kernels/`` shipped as ``pydynrad.kernels``) and the
native helpers in ``csrc/`` (the BVH builder, ray batches' checks, the hemicube runs' CSR, a move's segments near a sphere and its rows at the pose,
the far field's product with chosen columns, F's components, its copy by column and its columns
summed by cluster)."""

from setuptools import Extension, find_packages, setup

# pydynrad.<module>: csrc/<file>, each a small C extension with one job. No contraction of a
# multiply and an add into an FMA: the native sums that reproduce scipy's (G = F Pr) or numpy's
# bit for bit need their roundings (GCC in ISO C mode does not contract; clang does by default).
NATIVE = {
    "_bvh": "bvh.c",
    "_raybatch": "rays.c",
    "_runs": "runs.c",
    "_segments": "segments.c",
    "_poserows": "poserows.c",
    "_colproduct": "colproduct.c",
    "_csrgraph": "csrgraph.c",
}

setup(
    packages=[*find_packages(include=["pydynrad", "pydynrad.*"]), "pydynrad.kernels"],
    package_dir={"pydynrad": "pydynrad", "pydynrad.kernels": "kernels"},
    # py.typed: the package's inline annotations are for type checkers too (PEP 561).
    package_data={"pydynrad": ["py.typed"], "pydynrad.viewer": ["page.html"], "pydynrad.kernels": ["*.cl", "*.h"]},
    ext_modules=[
        Extension(
            f"pydynrad.{name}", sources=[f"csrc/{source}"], extra_compile_args=["-O3", "-std=c99", "-ffp-contract=off"]
        )
        for name, source in NATIVE.items()
    ],
)
