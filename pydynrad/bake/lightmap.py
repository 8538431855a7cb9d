"""Radiosity baked into a lightmap: a linear float texture over an automatic UV atlas.

* **UVs** from xatlas (the PyPI package of Jonathan Young's library), one xatlas mesh per
  surface: faces joined through the scene's smooth vertices (:mod:`pydynrad.smoothing`), which
  split at creases and material borders, so no chart spans one (xatlas alone joins coplanar
  faces at coincident positions: a road and the grass beside it). xatlas packs all charts into
  one image ``padding`` texels apart at ``texels_per_unit`` texels per scene unit of length.
* **Reconstruction** (``kernels/lightmap.cl`` finds each texel's triangle, the host computes
  the value in float64): every texel is the radiosity of its triangle at the texel's centre,
  interpolated linearly from the smooth-vertex values (what smooth shading in
  :func:`pydynrad.render` shows), not one flat value per patch. A texel within one texel of a
  triangle (one a bilinear lookup inside the triangle can reach) but whose centre lies outside
  it takes the triangle's plane extended to its centre, kept within the triangle's corner
  values; where several triangles reach a texel, the one it lies most inside wins. Bilinear
  filtering inside a triangle then reproduces the linear interpolation exactly wherever the
  four texels it reads belong to that triangle.
* **Dilation**: the remaining padding texels take the mean of their filled neighbours, ring
  by ring, ``padding`` rings out, so filtering and mipmapping at a chart's border read no
  black.

Texel (x, y) covers ``[x, x+1] x [y, y+1]`` in texel units, row 0 at the top of the image;
a vertex's ``uv`` is its texel position divided by (width, height), so ``(0, 0)`` is the
image's top-left corner, glTF's convention.

See docs/design.md, 'Baking'.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..checks import number, stops
from ..device.devices import default_device
from ..device.launch import enqueue_kernel, global_size, ray_work_group
from ..errors import InvalidInputError, OutOfMemoryError
from ..geometry.loading import checked_scene
from ..host.memory import available_host_bytes
from ..image_io import LINEAR_FORMATS, write_image
from ..progress import progress_bar
from ..smoothing import smooth_vertices
from .files import write_checked, write_pair
from .vertex import checked_mesh_path, mesh_bytes, mesh_metadata

__all__ = ["Lightmap", "bake_lightmap", "BYTES_PER_TEXEL"]

#: Host bytes a texel costs while baking at most: the image, its owner triangle and masks, and
#: for a filled texel its barycentrics and value temporaries (the device holds 9 bytes a texel).
BYTES_PER_TEXEL = 12 + 4 + 2 + 160
#: Most texels a lightmap may have: the kernels index texels with 32-bit integers.
MAX_TEXELS = 2**31 - 1


@dataclass
class Lightmap:
    """A baked lightmap and the mesh its UVs belong to.

    Attributes
    ----------
    image : (height, width, 3) float32
        Linear radiosity per texel (the unit of the scene's emission); 0 where nothing reached.
    covered : (height, width) bool
        Texels a triangle overlaps: the charts.
    filled : (height, width) bool
        Texels holding a value: the charts, their bilinear reach and the dilated padding.
    uv : (U, 2) float32
        Lightmap coordinates of each lightmap vertex, in [0, 1] (see the module docstring).
    faces : (N, 3) int64
        Lightmap vertices of each patch's corners (triangle i is patch i).
    vertex : (U,) int64
        The smooth vertex each lightmap vertex comes from (xatlas splits them along chart seams).
    vertex_radiosity : (U, 3) float64
        Radiosity of each lightmap vertex.
    positions : (U, 3) float32
        Position of each lightmap vertex, scene units.
    texels_per_unit, padding, crease_angle :
        The parameters it was baked with.
    scene_name, n_patches :
        The scene it was baked from, for the metadata of :meth:`write_mesh`.
    scene_unit, scene_up :
        Its metres per unit and up axis: :meth:`write_mesh` writes metres, +y up, as glTF
        specifies (None: the scene's own coordinates).
    """

    image: np.ndarray
    covered: np.ndarray
    filled: np.ndarray
    uv: np.ndarray
    faces: np.ndarray
    vertex: np.ndarray
    vertex_radiosity: np.ndarray
    positions: np.ndarray
    texels_per_unit: float
    padding: int
    crease_angle: float
    scene_name: str = "scene"
    n_patches: int = 0
    scene_unit: float | None = None
    scene_up: tuple | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) in texels."""
        return self.image.shape[:2]

    @property
    def coverage(self) -> float:
        """Fraction of the image's texels that lie in a chart."""
        return float(self.covered.mean())

    def sample(self, uv) -> np.ndarray:
        """(P, 3) float64 bilinear lookup at lightmap coordinates ``uv`` (P, 2), as a GPU's
        linear filter with clamp-to-edge reads the image."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        h, w = self.shape
        x = uv[:, 0] * w - 0.5
        y = uv[:, 1] * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        img = self.image.astype(np.float64)

        def tap(dx, dy):
            return img[np.clip(y0 + dy, 0, h - 1), np.clip(x0 + dx, 0, w - 1)]

        return (
            (1 - fx) * (1 - fy) * tap(0, 0)
            + fx * (1 - fy) * tap(1, 0)
            + (1 - fx) * fy * tap(0, 1)
            + fx * fy * tap(1, 1)
        )

    def patch_uv(self, patch, barycentric) -> np.ndarray:
        """(P, 2) lightmap coordinates of points given by patch index (P,) and barycentrics (P, 3)."""
        return np.einsum(
            "pk,pkd->pd",
            np.asarray(barycentric, dtype=np.float64),
            self.uv[self.faces[np.asarray(patch)]].astype(np.float64),
        )

    def write(self, path) -> Path:
        """Write the image as a linear float file (.exr, .hdr, .tif, .pfm; see :func:`pydynrad.image_io.write_image`)."""
        if Path(path).suffix.lower() not in LINEAR_FORMATS:
            raise InvalidInputError(
                f"a lightmap holds linear radiosity: write it as {', '.join(LINEAR_FORMATS)}, not {str(path)!r}"
            )
        return write_image(path, self.image)

    def write_mesh(self, path, *, exposure: float = 0.0, image_name: str | None = None, embed: bool = True) -> Path:
        """Write the lightmap's mesh as .glb: the lightmap UVs as ``TEXCOORD_0`` and ``TEXCOORD_1``
        (the second set, where engines look for lightmaps), the linear vertex radiosity as
        ``_RADIOSITY``, and the lightmap's size, texel density and file name in the metadata.

        ``embed``: the lightmap goes into the file as an 8-bit PNG, ``image * 2**exposure``
        clipped to [0, 1] and sRGB-encoded, the unlit material's base colour, so any glTF viewer
        shows it (the linear values are in the image :meth:`write` writes); otherwise the
        vertex colours of :func:`export_mesh` are written instead."""
        path = checked_mesh_path(path, (".glb",))
        exposure = stops(exposure)
        meta = mesh_metadata(
            self.scene_name, self.n_patches, exposure, self.crease_angle, unit=self.scene_unit, up=self.scene_up
        )
        h, w = self.shape
        meta["lightmap"] = {
            "image": image_name,
            "width": w,
            "height": h,
            "texels_per_unit": self.texels_per_unit,
            "padding_texels": self.padding,
            "uv_set": "TEXCOORD_1 (TEXCOORD_0 holds the same)",
            "uv_origin": "top-left of the image, v down",
        }
        texture = None
        if embed:
            texture = self._png(exposure)
            meta["lightmap"]["embedded"] = (
                "base colour texture: 8-bit PNG of radiosity * 2**exposure clipped to "
                "[0, 1], sRGB-encoded; no COLOR_0 (glTF would multiply it in)"
            )
        data = mesh_bytes(path, self.positions, self.faces, self.vertex_radiosity, meta, uv=self.uv, texture=texture)
        return write_checked(path, data)

    def write_pair(self, mesh_path, image_path, *, exposure: float = 0.0) -> tuple[Path, Path]:
        """Write the mesh (:meth:`write_mesh`, naming the image) and the image (:meth:`write`)
        as one pair: both whole to temporary names first, then the image renamed into place and
        the mesh last (:func:`pydynrad.bake.files.write_pair`), so a mesh never stands beside an
        image that is not its own, even when the process is killed; an exposure the mesh's 8-bit
        image refuses, or a full disk, leaves the old pair as it was. Temporaries killed writers
        of these names left are removed. Returns (mesh path, image path)."""
        image_path = Path(image_path)
        if image_path.suffix.lower() not in LINEAR_FORMATS:
            raise InvalidInputError(
                f"a lightmap holds linear radiosity: write it as {', '.join(LINEAR_FORMATS)}, not {str(image_path)!r}"
            )
        mesh_path = checked_mesh_path(mesh_path, (".glb",))
        exposure = stops(exposure)
        image, mesh = write_pair(
            image_path,
            self.write,
            mesh_path,
            lambda tmp: self.write_mesh(tmp, exposure=exposure, image_name=image_path.name),
        )
        return mesh, image

    def _png(self, exposure: float) -> bytes:
        """The image as an exposed, sRGB-encoded 8-bit PNG file's bytes."""
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            return write_image(Path(tmp) / "lightmap.png", self.image, exposure).read_bytes()


def _check_memory(texels: float, what: str) -> None:
    if texels > MAX_TEXELS:
        raise OutOfMemoryError(
            f"a lightmap of {what} would have {texels:.3g} texels, more than the {MAX_TEXELS} "
            "the kernels can index; lower texels_per_unit"
        )
    need = texels * BYTES_PER_TEXEL
    have = available_host_bytes()
    if need > have / 2:
        raise OutOfMemoryError(
            f"a lightmap of {what} would need {need / 2**30:.1f} GiB while baking, more than half "
            f"of the {have / 2**30:.1f} GiB available; lower texels_per_unit"
        )


#: The fewest texels the median patch may get in a lightmap.
MIN_TEXELS_PER_PATCH = 1.0


def check_texel_density(scene, texels_per_unit: float) -> None:
    """OutOfMemoryError where ``texels_per_unit`` would give a lightmap of ``scene`` larger than
    the kernels index or than half the host's memory, InvalidInputError where it would give the
    median patch fewer than :data:`MIN_TEXELS_PER_PATCH`: checkable before any solve."""
    tpu = float(texels_per_unit)
    _check_memory(float(scene.areas.sum(dtype=np.float64)) * tpu * tpu, f"{tpu:g} texels per unit")
    # Coarser than its patches, a lightmap averages neighbours into shared texels, and xatlas
    # floors the density it packs at (1e-9 gave 1e-3's atlas, recorded as 1e-9).
    texels = float(np.median(scene.areas)) * tpu * tpu
    if texels < MIN_TEXELS_PER_PATCH:
        raise InvalidInputError(
            f"{tpu:g} texels per unit gives the median patch {texels:.2g} texels; at least "
            f"{MIN_TEXELS_PER_PATCH:g} needs {np.sqrt(MIN_TEXELS_PER_PATCH / np.median(scene.areas)):.3g} "
            "per unit (or bake vertex colours, without --lightmap)"
        )


def _surfaces(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, int]:
    """(N,) label of each face's surface (faces joined through shared smooth vertices), and their count."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows = faces[:, [0, 1, 2]].reshape(-1)
    cols = faces[:, [1, 2, 0]].reshape(-1)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n_vertices, n_vertices))
    n, labels = connected_components(graph, directed=False)
    return labels[faces[:, 0]], n


def _atlas(positions: np.ndarray, faces: np.ndarray, texels_per_unit: float, padding: int):
    """(vertex, faces, uv, width, height): the atlas's vertices (each naming its smooth vertex),
    the faces over them in the scene's patch order, their uv in [0, 1], and the image size."""
    import xatlas

    # One xatlas mesh per surface: xatlas joins faces at coincident positions, which would let
    # a chart span a material border (a road meeting grass) that the smooth vertices split.
    surface, n_surfaces = _surfaces(faces, len(positions))
    order = np.argsort(surface, kind="stable")
    bounds = np.searchsorted(surface[order], np.arange(n_surfaces + 1))
    atlas = xatlas.Atlas()
    members = []
    for s in range(n_surfaces):
        mine = order[bounds[s] : bounds[s + 1]]
        used, local = np.unique(faces[mine], return_inverse=True)
        atlas.add_mesh(positions[used], local.reshape(-1, 3).astype(np.uint32))
        members.append((mine, used))
    pack = xatlas.PackOptions()
    pack.texels_per_unit = texels_per_unit
    pack.padding = padding
    pack.bilinear = True  # charts a full texel apart at least, so filtering never mixes two of them
    pack.resolution = 0  # one atlas, as large as the texel density needs
    atlas.generate(xatlas.ChartOptions(), pack)
    vertex, uvs, out_faces, offset = [], [], np.empty_like(faces, dtype=np.int64), 0
    for s, (mine, used) in enumerate(members):
        vmapping, indices, uv = atlas[s]
        out_faces[mine] = indices.reshape(-1, 3).astype(np.int64) + offset
        vertex.append(used[vmapping])
        uvs.append(uv)
        offset += len(vmapping)
    return (
        np.concatenate(vertex).astype(np.int64),
        out_faces,
        np.concatenate(uvs).astype(np.float32),
        int(atlas.width),
        int(atlas.height),
    )


def _rasterise(corners: np.ndarray, values: np.ndarray, h: int, w: int, device):
    """Per-texel value and masks from triangles ``corners`` (T, 3, 2) in texel units with
    vertex ``values`` (T, 3, 3); see the module docstring and ``kernels/lightmap.cl``."""
    import pyopencl as cl

    n = len(corners)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    area2 = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    lo = np.clip(np.floor(corners.min(axis=1) - 0.5), 0, [w - 1, h - 1]).astype(np.int64)
    hi = np.clip(np.floor(corners.max(axis=1) + 0.5), 0, [w - 1, h - 1]).astype(np.int64)
    box = np.zeros((n, 4), dtype=np.int32)
    box[:, :2] = lo
    box[:, 2:] = (hi - lo + 1) * (np.abs(area2) > 1e-12)[:, None]  # a zero-area triangle reaches nothing
    # Corners relative to their box, so float32 keeps a fraction of a texel's precision anywhere in the image.
    rel = np.ascontiguousarray((corners - lo[:, None, :]).astype(np.float32))
    mf = cl.mem_flags
    d_box, d_corner = device.to_device(box), device.to_device(rel.reshape(-1, 2))
    d_best = cl.Buffer(device.context, mf.READ_WRITE, 4 * h * w)
    d_owner = cl.Buffer(device.context, mf.READ_WRITE, 4 * h * w)
    d_covered = cl.Buffer(device.context, mf.READ_WRITE, h * w)
    cl.enqueue_fill_buffer(device.queue, d_best, np.int32(np.iinfo(np.int32).min), 0, 4 * h * w)
    cl.enqueue_fill_buffer(device.queue, d_owner, np.int32(-1), 0, 4 * h * w)
    cl.enqueue_fill_buffer(device.queue, d_covered, np.uint8(0), 0, h * w)
    size, local = (global_size(n),), (ray_work_group(device),)  # an item walks a triangle's texels
    best, owner_k = device.kernel("lightmap.cl", "lightmap_best"), device.kernel("lightmap.cl", "lightmap_owner")
    enqueue_kernel(device, best, size, local, np.int32(n), d_box, d_corner, np.int32(w), d_best, d_covered)
    enqueue_kernel(device, owner_k, size, local, np.int32(n), d_box, d_corner, np.int32(w), d_best, d_owner)
    owner = np.empty(h * w, dtype=np.int32)
    covered = np.empty(h * w, dtype=np.uint8)
    cl.enqueue_copy(device.queue, owner, d_owner)
    cl.enqueue_copy(device.queue, covered, d_covered, is_blocking=True)
    # Values on the host in float64, from the owner's corners: the texel centre's barycentrics,
    # the plane beyond the triangle kept within its corner values.
    texel = np.flatnonzero(owner >= 0)
    tri = owner[texel]
    px, py = texel % w + 0.5, texel // w + 0.5
    inv = 1.0 / area2[tri]
    bary = np.empty((len(tri), 3))
    for k, (p, q) in enumerate(((b, c), (c, a), (a, b))):
        p0, p1, q0, q1 = p[tri, 0], p[tri, 1], q[tri, 0], q[tri, 1]
        bary[:, k] = ((q0 - p0) * (py - p1) - (q1 - p1) * (px - p0)) * inv
    image = np.zeros((h * w, 3), dtype=np.float32)
    lin = sum(bary[:, k, None] * values[tri, k] for k in range(3))
    image[texel] = np.clip(lin, values.min(axis=1)[tri], values.max(axis=1)[tri])
    return image.reshape(h, w, 3), covered.reshape(h, w).astype(bool), (owner >= 0).reshape(h, w)


def _dilate(image: np.ndarray, filled: np.ndarray, rings: int) -> None:
    """Fill, in place, up to ``rings`` rings of unfilled texels around the filled ones with
    the mean of their filled 8-neighbours."""
    h, w = filled.shape
    for _ in range(rings):
        weight = np.zeros((h + 2, w + 2), dtype=np.float32)
        weight[1:-1, 1:-1] = filled
        masked = np.zeros((h + 2, w + 2, 3), dtype=np.float32)
        masked[1:-1, 1:-1] = image * weight[1:-1, 1:-1, None]
        total = np.zeros((h, w, 3), dtype=np.float32)
        count = np.zeros((h, w), dtype=np.float32)
        for dy in (0, 1, 2):
            for dx in (0, 1, 2):
                if (dx, dy) != (1, 1):
                    total += masked[dy : dy + h, dx : dx + w]
                    count += weight[dy : dy + h, dx : dx + w]
        grow = ~filled & (count > 0)
        if not grow.any():
            break
        image[grow] = total[grow] / count[grow][:, None]
        filled |= grow


def bake_lightmap(
    scene,
    radiosity,
    texels_per_unit: float,
    *,
    padding: int = 2,
    crease_angle: float = 30.0,
    device=None,
    progress: bool | None = None,
) -> Lightmap:
    """Bake a radiosity solution into a lightmap.

    Parameters
    ----------
    scene : Scene
    radiosity : (N, 3) or (N,) float
        Patch radiosity (e.g. ``pydynrad.solve(...).radiosity``), finite.
    texels_per_unit : float
        Texel density: texels per scene unit of length (the Cornell box is in mm: 0.1 is one
        texel per cm). The image has about ``total area * texels_per_unit**2 / utilisation``
        texels; refused before any allocation when that would not fit in memory.
    padding : int
        Texels between charts (>= 1), filled by dilation.
    crease_angle : float
        Degrees; see :func:`pydynrad.render`.
    device : Device, optional
        Runs the rasterising kernels (``kernels/lightmap.cl``); the process default when omitted.
    progress : bool, optional
        A tqdm bar over the bake's stages (smooth vertices, atlas, rasterise, dilate); None:
        once the bake has taken two seconds (:mod:`pydynrad.progress`); False: never.

    Returns
    -------
    Lightmap
        Write it with :meth:`Lightmap.write` (EXR) and :meth:`Lightmap.write_mesh` (GLB).
    """
    scene = checked_scene(scene)
    tpu = number(texels_per_unit, "texels_per_unit")
    if not tpu > 0:
        raise InvalidInputError(f"texels_per_unit must be > 0; got {texels_per_unit!r}")
    if isinstance(padding, bool) or not isinstance(padding, (int, np.integer)) or not 1 <= padding <= 64:
        raise InvalidInputError(f"padding must be a whole number of texels in 1..64; got {padding!r}")
    # xatlas reports nothing while it packs, so the bar counts stages: its time, not a fraction.
    with progress_bar(progress, total=4, desc="bake lightmap", unit="stage") as bar:
        smooth = smooth_vertices(scene, crease_angle)
        values = smooth.radiosity(radiosity)  # checks the radiosity before the atlas is built
        check_texel_density(scene, tpu)
        bar.update(1)
        vmapping, faces, uv, w, h = _atlas(smooth.positions, smooth.corner_vertex, tpu, int(padding))
        _check_memory(float(w) * h, f"{w}x{h} texels")
        vertex_values = values[vmapping]
        corners = (uv.astype(np.float64) * [w, h])[faces]
        bar.update(1)
        image, covered, filled = _rasterise(corners, vertex_values[faces], h, w, device or default_device())
        bar.update(1)
        _dilate(image, filled, int(padding))
        bar.update(1)
    return Lightmap(
        image=image,
        covered=covered,
        filled=filled,
        uv=uv,
        faces=faces,
        vertex=vmapping,
        vertex_radiosity=vertex_values,
        positions=smooth.positions[vmapping],
        texels_per_unit=tpu,
        padding=int(padding),
        crease_angle=float(crease_angle),
        scene_name=scene.name,
        n_patches=len(scene),
        scene_unit=float(scene.unit),
        scene_up=tuple(float(x) for x in scene.up),
    )
