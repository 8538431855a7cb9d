import time, sys, numpy as np, pydynrad.device.launch as L
from pydynrad.device.devices import default_device
from pydynrad.device.matrix import DeviceMatrix
dev = default_device(); rng = np.random.default_rng(0)
new_grid = L.MatvecLayout.matvec_grid
def old_grid(self, M, nrhs=1):
    return (L.global_size(M),), None
for M in map(int, sys.argv[1].split(",")):
    for st in sys.argv[2].split(","):
        K = rng.random((1, M, M)) * 1e-3; x = rng.random((1, M))
        L.MATVEC_CHAINS = 1; old = DeviceMatrix(dev, K, st)
        L.MATVEC_CHAINS = 4; new = DeviceMatrix(dev, K, st)
        cfg = {"main": (old, old_grid), "branch": (new, new_grid)}
        ts = {(c, w): [] for c in cfg for w in ("host", "kern")}
        for rep in range(int(sys.argv[3])):
            for c, (m, grid) in cfg.items():
                L.MatvecLayout.matvec_grid = grid
                if rep == 0: m.matvec(x)
                t = time.perf_counter(); y = m.matvec(x); ts[c, "host"].append(time.perf_counter() - t)
                xb, yb = m._buffers(0); t = time.perf_counter(); m.enqueue_matvec(0, xb, yb); dev.queue.finish()
                ts[c, "kern"].append(time.perf_counter() - t)
        print(f"M={M} {st} RI={new._layout.rows_per_item(1)}: " + "  ".join(f"{c}-{w} min {min(v)*1e6:.0f} med {np.median(v)*1e6:.0f}" for (c, w), v in ts.items()), flush=True)
