"""Row sources and the bounded row cache: LRU eviction under a byte limit, prefetch, streamed = in-memory."""

import threading

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import grid_scene, reciprocal_F, same_csr, synthetic_rows

from pydynrad import InvalidInputError
from pydynrad.dynamic import DynamicRadiosity
from pydynrad.precompute.store import compute_store
from pydynrad.rows.cache import ROW_OVERHEAD, RowCache
from pydynrad.rows.sources import CSRRows, RowSource, as_row_source
from pydynrad.rows.store import StoreCorruptError


class CountingSource:
    """A RowSource over an in-memory matrix that records every row it is asked for."""

    def __init__(self, matrix, gate: threading.Event | None = None):
        self.inner = CSRRows(matrix)
        self.n_patches = self.inner.n_patches
        self.reads: list[int] = []
        self.gate = gate

    def rows(self, idx):
        if self.gate is not None:
            self.gate.wait(5)
        self.reads += [int(i) for i in idx]
        return self.inner.rows(idx)


def fixed_width_matrix(n: int, nnz_per_row: int) -> sp.csr_matrix:
    rng = np.random.default_rng(1)
    cols = np.sort(np.stack([rng.choice(n, nnz_per_row, replace=False) for _ in range(n)]), axis=1)
    vals = rng.random((n, nnz_per_row)).astype(np.float32) / (2 * nnz_per_row)
    return sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(0, n * nnz_per_row + 1, nnz_per_row)), shape=(n, n))


def test_row_sources_agree():
    f = fixed_width_matrix(50, 5)
    assert isinstance(as_row_source(f), CSRRows) and isinstance(as_row_source(f.toarray()), CSRRows)
    src = as_row_source(f)
    assert as_row_source(src) is src and isinstance(src, RowSource)
    idx = [7, 0, 49, 7]
    assert same_csr(src.rows(idx), f[idx])
    with RowCache(src, max_bytes=10**6) as cache:
        assert isinstance(cache, RowSource) and cache.n_patches == 50
        assert same_csr(cache.rows(idx), f[idx])
        assert same_csr(cache.rows(idx), f[idx])  # now from the cache
        assert cache.rows([]).shape == (0, 50)
        with pytest.raises(InvalidInputError, match="0..49"):
            cache.rows([50])
    with pytest.raises(InvalidInputError, match="square"):
        as_row_source(sp.csr_matrix((3, 4)))
    with pytest.raises(InvalidInputError, match="RowSource"):
        as_row_source([[1.0]])
    with pytest.raises(InvalidInputError, match="max_bytes"):
        RowCache(src, max_bytes=-1)


def test_lru_eviction_under_byte_limit():
    f = fixed_width_matrix(40, 10)
    row_cost = 10 * 8 + ROW_OVERHEAD  # int32 index + float32 value per non-zero
    src = CountingSource(f)
    cache = RowCache(src, max_bytes=3 * row_cost + row_cost // 2)  # room for three rows
    cache.rows([0, 1, 2])
    assert len(cache) == 3 and cache.nbytes == 3 * row_cost
    cache.rows([0])  # 0 becomes the most recently used: 1 is now the oldest
    cache.rows([3])
    assert sorted(cache._rows) == [0, 2, 3] and cache.stats["evictions"] == 1
    src.reads.clear()
    assert same_csr(cache.rows([2, 0, 3]), f[[2, 0, 3]]) and src.reads == []  # all hits
    assert same_csr(cache.rows([1]), f[[1]]) and src.reads == [1]  # evicted, so read again
    # A request larger than the cache is still served whole; the cache keeps only its budget.
    big = np.arange(10, 30)
    assert same_csr(cache.rows(big), f[big])
    assert cache.nbytes <= cache.max_bytes and len(cache) == 3 and cache.peak_nbytes <= cache.max_bytes
    assert sorted(cache._rows) == [27, 28, 29]
    s = cache.stats
    assert s["requested"] == s["hits"] + s["misses"] and s["prefetch_hits"] == 0
    assert RowCache(src, max_bytes=0).rows([5]).nnz == 10  # a zero budget caches nothing but still serves
    cache.close()


def test_prefetch_reads_in_background():
    f = fixed_width_matrix(60, 4)
    gate = threading.Event()
    src = CountingSource(f, gate=gate)
    with RowCache(src, max_bytes=10**6) as cache:
        fut = cache.prefetch([5, 6, 7])
        assert fut is not None and not fut.done()  # returned at once, the read waits on the gate
        assert cache.prefetch([6, 7]) is None  # already on its way: not queued twice
        gate.set()
        got = cache.rows([7, 8])  # 7 is waited for, 8 read in the foreground
        assert same_csr(got, f[[7, 8]])
        fut.result()
        assert sorted(src.reads) == [5, 6, 7, 8]  # nothing read twice
        src.reads.clear()
        assert same_csr(cache.rows([5, 6]), f[[5, 6]]) and src.reads == []
        assert cache.stats["prefetched"] == 3 and cache.stats["prefetch_hits"] == 3 and cache.stats["misses"] == 1


def test_concurrent_readers_get_right_rows():
    f = fixed_width_matrix(200, 6)
    cache = RowCache(CSRRows(f), max_bytes=40 * (6 * 8 + ROW_OVERHEAD))
    errors = []

    def reader(seed):
        rng = np.random.default_rng(seed)
        for _ in range(60):
            idx = rng.integers(0, 200, size=12)
            if rng.random() < 0.3:
                cache.prefetch(rng.integers(0, 200, size=8))
            if not same_csr(cache.rows(idx), f[idx]):
                errors.append(seed)

    threads = [threading.Thread(target=reader, args=(s,)) for s in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    cache.close()
    assert errors == [] and cache.nbytes <= cache.max_bytes


def local_sets(scene, m: int, steps: int):
    """The M patches nearest an observer walking diagonally across the scene, per frame."""
    lo, hi = scene.bbox.astype(np.float64)
    for t in np.linspace(0, 1, steps):
        eye = lo + t * (hi - lo) + np.array([0, 0, 0.5])
        yield np.argsort(np.linalg.norm(scene.centers - eye, axis=1), kind="stable")[: 2 * m]


def test_streamed_rows_equal_in_memory_rows_along_a_walk(tmp_path):
    """Store -> cache smaller than the store -> the rows a walk needs equal the in-memory rows."""
    scene = grid_scene(20)  # 800 patches
    store = compute_store(
        scene, tmp_path / "ff", resolution=8, block_rows=32, progress=False, row_function=synthetic_rows
    )
    memory = CSRRows(store.to_csr())
    assert same_csr(memory.matrix, synthetic_rows(scene, np.arange(800), 8))
    store_payload = memory.nbytes
    m = 64
    with RowCache(store, max_bytes=store_payload // 4) as cache:
        local = np.zeros(0, dtype=np.int64)
        for ranked in local_sets(scene, m, steps=25):
            new_local, candidates = ranked[:m], ranked[m:]
            entering = np.setdiff1d(new_local, local)
            assert same_csr(cache.rows(entering), memory.rows(entering))
            assert same_csr(cache.rows(new_local), memory.rows(new_local))
            cache.prefetch(candidates)  # the patches next in line to enter
            local = new_local
            assert cache.nbytes <= cache.max_bytes
        s = cache.stats
    assert s["prefetch_hits"] > 0 and s["evictions"] > 0
    assert s["hits"] + s["misses"] == s["requested"]


def test_store_errors_pass_through_the_cache(tmp_path):
    scene = grid_scene(4)  # 32 patches
    store = compute_store(
        scene, tmp_path / "ff", resolution=8, block_rows=8, progress=False, row_function=synthetic_rows
    )
    good = store.rows([0])
    store.block_path(1).write_bytes(b"not a zip")
    with RowCache(store, max_bytes=10**6) as cache:
        fut = cache.prefetch([9, 10])
        with pytest.raises(StoreCorruptError):
            fut.result()
        with pytest.raises(StoreCorruptError):  # never served, never cached
            cache.rows([9])
        assert len(cache) == 0 and same_csr(cache.rows([0]), good)


def test_streamed_walk_equals_in_memory_walk(tmp_path, device):
    """DynamicRadiosity fed from a store through a cache smaller than F = fed from F in memory."""
    scene = grid_scene(12)  # 288 patches
    emission = np.zeros(len(scene))
    emission[::37] = 1.0
    scene = scene.with_materials(albedo=0.6, emission=emission)
    f = sp.csr_matrix(reciprocal_F(scene.areas, row_sum=0.9, density=0.02, seed=3), dtype=np.float32)
    store = compute_store(
        scene,
        tmp_path / "ff",
        resolution=8,
        block_rows=32,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: f[rows],
    )
    cache = RowCache(store, max_bytes=CSRRows(f).nbytes // 3)
    sources = {"rows in memory": CSRRows(f), "streamed": cache, "matrix in memory": f}
    walks = {
        name: DynamicRadiosity(
            scene,
            src,
            local_size=48,
            update="exact",
            storage="fp64",
            max_swaps_per_frame=6,
            far_field=False,
            device=device,
        )
        for name, src in sources.items()
    }
    lo, hi = scene.bbox.astype(np.float64)
    swaps = 0
    for t in np.linspace(0, 1, 12):
        eye = lo + t * (hi - lo) + np.array([0, 0, 1.0])
        stats = {name: w.update(eye) for name, w in walks.items()}
        swaps += stats["streamed"].swaps
        b = {name: w.radiosity() for name, w in walks.items()}
        assert np.array_equal(walks["streamed"].local_mask, walks["rows in memory"].local_mask)
        assert np.array_equal(walks["streamed"].local_mask, walks["matrix in memory"].local_mask)
        # Same rows, same arithmetic: bit for bit.
        np.testing.assert_array_equal(b["streamed"], b["rows in memory"])
        # The in-memory matrix reads F[S, J] from its columns, the row sources from the rows of
        # S: the same numbers, so the same result.
        np.testing.assert_array_equal(b["streamed"], b["matrix in memory"])
    assert walks["streamed"].local_mask.sum() == 48 and swaps > 0
    assert cache.stats["misses"] > 0 and cache.nbytes <= cache.max_bytes < CSRRows(f).nbytes
    cache.close()
