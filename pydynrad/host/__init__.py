"""Host numerics beside the device: BLAS threads, small products, sparse graphs, memory limits.

* :mod:`.product`: small products held on the host where the device is the host's own CPU;
* :mod:`.blas` and :mod:`.threads`: BLAS thread limits and a thread pool for row parts;
* :mod:`.colproduct` and :mod:`.csrgraph`: native helpers over CSR matrices (``csrc/``);
* :mod:`.anderson`: Anderson acceleration of fixed-point sweeps;
* :mod:`.memory`: how many bytes the host can still give.

Nothing here imports the device layer, the geometry or the solvers.
"""
