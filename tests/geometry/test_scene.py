import numpy as np
import pytest

import pydynrad
from pydynrad import InvalidInputError, Scene
from pydynrad.geometry import DegenerateTriangleWarning

SQUARE_PTS = [[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]]
SQUARE_TRI = [[0, 1, 2], [0, 2, 3]]


def square(**kw):
    return Scene(SQUARE_PTS, SQUARE_TRI, **kw)


def test_derived_geometry_matches_hand_computation():
    s = square()
    np.testing.assert_allclose(s.areas, [3.0, 3.0])
    np.testing.assert_allclose(s.normals, [[0, 0, 1], [0, 0, 1]])
    np.testing.assert_allclose(s.centers[0], [4 / 3, 1, 0], rtol=1e-6)
    assert s.triangles.shape == (2, 3, 3)
    assert s.scale == pytest.approx(np.sqrt(13.0))
    assert len(s) == s.n_patches == 2


def test_materials_broadcast_and_grey_detection():
    assert square(albedo=0.3).is_grey
    s = square(albedo=[0.1, 0.2, 0.3], emission=[[1, 1, 1], [0, 0, 0]])
    assert not s.is_grey
    assert s.albedo.shape == (2, 3) and s.albedo.dtype == np.float32
    np.testing.assert_array_equal(s.emitters, [0])


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(albedo=1.0), "albedo"),
        (dict(albedo=-0.1), "albedo"),
        (dict(albedo=[0.5, np.nan, 0.5]), "albedo"),
        (dict(emission=-1.0), "emission"),
        (dict(emission=np.inf), "emission"),
        (dict(albedo=np.zeros((3, 3))), "albedo"),
        (dict(source_face=[0]), "source_face"),
    ],
)
def test_bad_materials_are_named(kwargs, needle):
    with pytest.raises(InvalidInputError, match=needle):
        square(**kwargs)


def test_bad_geometry_is_named():
    with pytest.raises(InvalidInputError, match="NaN or infinite"):
        Scene([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]])
    with pytest.raises(InvalidInputError, match="empty"):
        Scene(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(InvalidInputError, match="outside"):
        Scene(SQUARE_PTS, [[0, 1, 7]])
    with pytest.raises(InvalidInputError, match="integer"):
        Scene(SQUARE_PTS, [[0.0, 1.0, 2.0]])
    # The error is also a ValueError, so generic callers catch it.
    with pytest.raises(ValueError):
        Scene(SQUARE_PTS, [[0, 1]])


def test_zero_area_triangles_are_dropped_and_counted():
    pts = SQUARE_PTS + [[4, 0, 0]]
    tris = [[0, 1, 2], [0, 1, 4], [1, 1, 2], [0, 2, 3]]  # two collinear/degenerate
    with pytest.warns(DegenerateTriangleWarning, match="dropped 2 zero-area"):
        s = Scene(pts, tris, albedo=[[0.1] * 3, [0.2] * 3, [0.3] * 3, [0.4] * 3])
    np.testing.assert_array_equal(s.source_face, [0, 3])
    np.testing.assert_allclose(s.albedo[:, 0], [0.1, 0.4])
    with pytest.raises(InvalidInputError, match="zero area"):
        Scene(pts, [[0, 1, 4]])


def test_tiny_and_huge_patches_survive():
    for scale in (1e-6, 1e6):
        s = Scene(np.asarray(SQUARE_PTS, dtype=float) * scale, SQUARE_TRI)
        np.testing.assert_allclose(s.areas, 3.0 * scale**2, rtol=1e-6)
        np.testing.assert_allclose(s.normals[:, 2], 1.0, rtol=1e-6)


def test_with_materials_keeps_geometry_and_bvh():
    s = square(albedo=0.5)
    bvh = s.bvh
    t = s.with_materials(albedo=[0.2, 0.4, 0.6], emission=1.0)
    assert t.bvh is bvh
    assert t.geometry_hash() == s.geometry_hash()
    assert t.content_hash() != s.content_hash()
    np.testing.assert_allclose(s.albedo, 0.5)  # the original is untouched
    with pytest.raises(InvalidInputError, match="albedo"):
        s.with_materials(albedo=1.5)


def test_repr_names_the_scene():
    assert "2 patches" in repr(square())
    assert isinstance(pydynrad.__version__, str)


def test_areas_that_overflow_are_not_called_zero():
    """Coordinates beyond ~1e154 overflow the cross product: named so, not as zero-area triangles."""
    with pytest.raises(InvalidInputError, match="overflow float64"):
        Scene(np.array([[0, 0, 0], [1e160, 0, 0], [0, 1e160, 0.0]]), [[0, 1, 2]])
