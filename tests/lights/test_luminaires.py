"""Luminaires: IES LM-63 and EULUMDAT files read back against their tables, intensity
distributions on the device against the host, orientation, Lambertian source, flux conservation."""

import math

import numpy as np
import pytest

import pydynrad
from bench.cie171_data import LM63_EXAMPLE
from pydynrad import InvalidInputError
from pydynrad.lights import (
    IESFormatError,
    LuminaireLight,
    PhotometricDistribution,
    parse_ies,
    parse_ldt,
    read_ies,
    read_ldt,
)
from pydynrad.photometry import illuminance

# The candela table of the LM-63-2002 standard's example file (LM63_EXAMPLE: TILT=INCLUDE,
# quadrant symmetry), one row per horizontal angle 0, 45, 90.
LM63_TABLE = np.array(
    [[10000, 50000, 25000, 10000, 5000], [10000, 35000, 16000, 8000, 3000], [10000, 20000, 10000, 5000, 1000]], float
)


def ldt_text(isym, mc, dc, gammas, planes, flux=2000.0, conversion=1.0):
    """A EULUMDAT file laid out line by line as the format prescribes, one value per line."""
    lines = [
        "pydynrad test company",
        "1",
        str(isym),
        str(mc),
        str(dc),
        str(len(gammas)),
        str(gammas[1] - gammas[0]),
        "report 42",
        "Test downlight",
        "TD-1",
        "td1.ldt",
        "2026-12-01 test",
        "200",
        "0",
        "100",
        "180",
        "0",
        "0",
        "0",
        "0",
        "0",
        "100",
        "85",
        str(conversion),
        "0",
        "1",
        "1",
        "LED",
        str(flux),
        "3000K",
        "1B",
        "20",
        *["0.5"] * 10,
        *[f"{k * dc:g}" for k in range(mc)],
        *[f"{g:g}" for g in gammas],
    ]
    lines += [f"{v:.10g}" for plane in planes for v in plane]
    return "\n".join(lines) + "\n"


def test_lm63_example_reads_back_its_candela_table():
    d = parse_ies(LM63_EXAMPLE)
    assert d.name == "Wide beam flood to be used without tilt" and d.lumens == 50000
    gammas = [0, 22.5, 45, 67.5, 90]
    for c, row in zip((0, 45, 90), LM63_TABLE):
        np.testing.assert_array_equal(d.intensity(c, gammas), row)
    # Quadrant symmetry: C and 180 - C, 180 + C, 360 - C carry the same plane.
    for c in (0, 45, 90):
        for image in (180 - c, 180 + c, 360 - c):
            np.testing.assert_array_equal(d.intensity(image, gammas), d.intensity(c, gammas))
    # Bilinear between table angles, 0 beyond the last vertical angle.
    assert d.intensity(22.5, 22.5) == pytest.approx((50000 + 35000) / 2)
    assert d.intensity(0, 11.25) == pytest.approx(30000)
    assert d.intensity(0, 120.0) == 0.0
    # TILT=INCLUDE: the factor at the installed tilt (linear between the file's angles).
    np.testing.assert_allclose(parse_ies(LM63_EXAMPLE, tilt=15).candela, parse_ies(LM63_EXAMPLE).candela * 0.95)


def test_ldt_files_read_back_their_tables(tmp_path):
    gammas = np.arange(0, 181, 10.0)
    plane = 1000.0 * np.cos(np.radians(np.minimum(gammas, 90)))  # cd/klm
    path = tmp_path / "downlight.ldt"
    path.write_text(ldt_text(1, 24, 15, gammas, [plane], flux=2000.0, conversion=1.0))
    d = read_ldt(path)
    assert d.name == "Test downlight" and d.lumens == 2000.0 and len(d.c_angles) == 1
    np.testing.assert_allclose(d.intensity(123.0, gammas), plane * 2.0)  # cd/klm times 2 klm
    # Isym 4 (C0-C90 given): the plane at C = 30 reappears at 150, 210 and 330.
    planes = [plane * (1 + k / 10) for k in range(7)]  # C = 0, 15, ..., 90
    d4 = parse_ldt(ldt_text(4, 24, 15, gammas, planes, flux=1000.0, conversion=0.5))
    for c in (30, 150, 210, 330):
        np.testing.assert_allclose(d4.intensity(c, gammas), planes[2] * 0.5)
    # Isym 3 (C270..C90 through C0 given): C = 60 mirrors to 120.
    planes3 = [plane * (1 + k / 10) for k in range(13)]  # C = 270, 285, ..., 360/0, ..., 90
    d3 = parse_ldt(ldt_text(3, 24, 15, gammas, planes3))
    np.testing.assert_allclose(d3.intensity(60, gammas), planes3[10] * 2.0)
    np.testing.assert_allclose(d3.intensity(120, gammas), planes3[10] * 2.0)
    np.testing.assert_allclose(d3.intensity(300, gammas), planes3[2] * 2.0)


def test_malformed_files_name_the_offending_line():
    bad = LM63_EXAMPLE.replace("10000 35000 16000 8000 3000", "10000 35000 l6000 8000 3000")
    with pytest.raises(IESFormatError, match=r"line 25: expected a number \(candela values.*'l6000'"):
        parse_ies(bad)
    with pytest.raises(IESFormatError, match=r"line 26 \(end of file\): expected 15 candela values"):
        parse_ies(LM63_EXAMPLE.rsplit("10000 20000", 1)[0])
    with pytest.raises(IESFormatError, match="line 15: TILT=LAMP.IES is not supported"):
        parse_ies(LM63_EXAMPLE.replace("TILT=INCLUDE", "TILT=LAMP.IES"))
    with pytest.raises(IESFormatError, match="line 20: photometric type 2"):
        parse_ies(LM63_EXAMPLE.replace("1 50000 1 5 3 1 1", "1 50000 1 5 3 2 1"))
    gammas = np.arange(0, 181, 10.0)
    text = ldt_text(1, 24, 15, gammas, [np.ones(len(gammas))]).splitlines()
    text[2] = "7"
    with pytest.raises(IESFormatError, match=r"line 3: the symmetry indicator Isym must be an integer in 0..4"):
        parse_ldt("\n".join(text))
    text = ldt_text(1, 24, 15, gammas, [np.ones(len(gammas))]).splitlines()
    with pytest.raises(IESFormatError, match=rf"line {len(text)} \(end of file\)"):  # the missing last line
        parse_ldt("\n".join(text[:-1]))
    with pytest.raises(InvalidInputError, match="cannot read"):
        read_ies("/nonexistent/lamp.ies")


def _plate(n=8, size=4.0):
    g = np.linspace(-size / 2, size / 2, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    q = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)[:-1, :-1].ravel()
    tris = np.concatenate([np.stack([q, q + n + 1, q + n + 2], 1), np.stack([q, q + n + 2, q + 1], 1)])
    return pydynrad.Scene(pts, tris, albedo=0.5)


def test_device_distribution_matches_the_host_and_follows_orientation(device):
    d = parse_ies(LM63_EXAMPLE)
    scene = _plate()
    pos = np.array([0.4, -0.3, 1.5])
    # Tilted: nadir 30 degrees off straight down, C0 along y.
    nadir = np.array([math.sin(math.radians(30)), 0.0, -math.cos(math.radians(30))])
    lum = LuminaireLight(pos, d, nadir=nadir, c0=(0, 1, 0), scale=(1.0, 0.5, 0.25))
    H = pydynrad.lights.direct_irradiance(scene, [lum], device)
    v = scene.centers - pos
    r = np.linalg.norm(v, axis=1)
    expected = lum.intensity_towards(v / r[:, None]) * (-v[:, 2] / r) / r**2
    # float32 angles on the device: 2.7e-6 relative observed.
    np.testing.assert_allclose(H[:, 0], expected, rtol=3e-5, atol=1e-5 * expected.max())
    np.testing.assert_allclose(H[:, 1], 0.5 * H[:, 0], rtol=1e-6)
    # Rotating the C0 axis by 90 degrees about the nadir turns the distribution with it.
    turned = LuminaireLight(pos, d, nadir=nadir, c0=np.cross(-nadir, [0, 1, 0]))
    c, gamma = 37.0, 50.0
    assert turned.intensity_towards(_direction(turned, c, gamma)) == pytest.approx(d.intensity(c, gamma))


def _direction(lum, c, gamma):
    c, g = math.radians(c), math.radians(gamma)
    return math.cos(g) * np.asarray(lum.nadir) + math.sin(g) * (
        math.cos(c) * np.asarray(lum.c0) + math.sin(c) * np.asarray(lum.c90)
    )


def test_lambertian_point_source(device):
    I0 = 500.0
    lam = PhotometricDistribution.lambertian(I0)
    assert lam.flux() == pytest.approx(math.pi * I0, rel=1e-5)
    pos = np.array([0.3, 0.2, 2.0])
    points = np.array([[0.0, 0.0, 0.0], [1.5, -1.0, 0.0], [3.0, 2.0, 0.0], [0.3, 0.2, 1.0]])
    E = illuminance(_plate(), None, points, [0, 0, 1], lights=LuminaireLight(pos, lam), device=device)
    v = pos - points
    r = np.linalg.norm(v, axis=1)
    cos = v[:, 2] / r  # the source's cos(gamma) equals the receiver's cos for a horizontal plane
    np.testing.assert_allclose(E[:, 0], I0 * cos * cos / r**2, rtol=1e-5)


def test_a_luminaire_near_float32s_limit_meets_its_inverse_square_law(device):
    # A millimetre scene is scaled to its own size on the device (1/unit^2 on the light's factor,
    # unit^2/d^2 from the distance): with the table's candela taken first, 1e37 cd and up had
    # overflowed float32 and been refused as irradiance overflow at ~2e33. Linear to 3e38 cd.
    box = pydynrad.scenes.cornell_box(max_edge=200.0)
    # (Issue 41: the box declares millimetres, so irradiance is per m^2: 3e38 cd at 0.27 m would be
    # 4e39 lx, beyond float32 for the answer itself, and the lamp is 9 mm under the ceiling.)
    E = [
        pydynrad.lights.direct_irradiance(
            box, [LuminaireLight((278, 540, 280), PhotometricDistribution.lambertian(peak))], device
        ).astype(np.float64)
        / peak
        for peak in (1.0, 1e32, 1e33)
    ]
    assert np.isfinite(E[2]).all() and E[0].max() > 0
    np.testing.assert_allclose(E[1], E[0], rtol=1e-6)
    np.testing.assert_allclose(E[2], E[0], rtol=1e-6)


def test_flux_is_conserved_in_a_closed_black_room(device):
    # CIE 171:2006, 5.4: all the flux of a luminaire inside a closed room arrives on its walls.
    room = pydynrad.scenes.closed_box((4.0, 3.0, 2.5), subdivisions=4, albedo=0.0, emission=0.0)
    d = parse_ies(LM63_EXAMPLE)
    lum = LuminaireLight([1.5, 1.2, 1.8], d, nadir=(0.2, 0.1, -1.0))
    H = pydynrad.lights.direct_irradiance(room, [lum], device).astype(np.float64)
    arriving = float(np.sum(H[:, 0] * room.areas))
    # Patch-centre quadrature on 9,216 patches: 0.043% off the distribution's flux (whose own
    # quadrature is good to 3e-7).
    assert arriving == pytest.approx(d.flux(), rel=3e-3)


def test_bad_luminaires_are_refused():
    d = PhotometricDistribution.isotropic(100.0)
    with pytest.raises(InvalidInputError, match="parallel"):
        LuminaireLight([0, 0, 0], d, nadir=(0, 0, -1), c0=(0, 0, 2))
    with pytest.raises(InvalidInputError, match="PhotometricDistribution"):
        LuminaireLight([0, 0, 0], "lamp.ies")
    with pytest.raises(InvalidInputError, match="candela values must be finite and >= 0"):
        PhotometricDistribution([0.0], [0.0, 90.0], [[1.0, -1.0]])


def test_solve_and_path_tracer_agree_under_a_luminaire(device):
    room = pydynrad.scenes.closed_box((4.0, 3.0, 2.5), subdivisions=2, albedo=0.5, emission=0.0)
    lum = LuminaireLight([1.5, 1.2, 2.3], parse_ies(LM63_EXAMPLE), nadir=(0.2, 0.1, -1.0))
    F = pydynrad.form_factors(room, 64, device=device)
    B = pydynrad.solve(room, F, lights=[lum], device=device).radiosity
    P = pydynrad.pathtracer.path_trace_patches(room, spp=1024, lights=[lum], device=device).astype(np.float64)
    rel = (P - B) / B
    # Both share lights.h's direct term; the indirect part differs by 1,024-path noise and by
    # constant-radiosity patches: 3.2% RMS per patch, 0.03% on the mean over 576 patches.
    assert np.sqrt(np.mean(rel**2)) < 0.05
    assert abs(np.mean(rel)) < 0.005


def _ies(header="1 1000 1.0 3 1 1 2 0.5 0.5 0.1", vert="0 45 90", horiz="0", cd="100 80 60", tilt="TILT=NONE"):
    return "\n".join(["IESNA:LM-63-2002", "[LUMINAIRE] probe", tilt, header, "1 1 0", vert, horiz, cd]) + "\n"


@pytest.mark.parametrize(
    "text, message",
    [
        (_ies(header="1 1000 1.0 inf 1 1 2 0.5 0.5 0.1"), "line 4: expected a finite number"),  # had crashed int()
        (_ies(vert="0 nan 90"), "line 6: expected a finite number"),
        (
            _ies(header="1 1000 1.0 3 4 1 2 0.5 0.5 0.1", horiz="0 90 180 270 360", cd="100 80 60\n" * 5),
            "value.s. after the candela table",
        ),  # the counts say 4 planes: every value had shifted by one
        (_ies(header="1 1000 -2.0 3 1 1 2 0.5 0.5 0.1"), "line 4: the candela multiplier"),
        (_ies(tilt="TILT=INCLUDE\n1\n3\n90 45 0\n1.0 0.9 0.8"), "tilt angles must increase"),
    ],
)
def test_ies_files_that_would_have_crashed_or_shifted_are_named(text, message):
    with pytest.raises(IESFormatError, match=message):
        parse_ies(text, "probe.ies")


def test_nan_angles_and_undeclared_ldt_symmetry_are_refused():
    with pytest.raises(InvalidInputError, match="must be finite"):
        PhotometricDistribution([0.0, np.nan, 360.0], [0.0, 90.0], np.ones((3, 2)))
    # Isym = 0 declares no symmetry: planes over 0..90 had been mirrored round the circle.
    text = ldt_text(0, 2, 90.0, [0.0, 90.0], [[100.0, 50.0], [80.0, 40.0]])
    with pytest.raises(IESFormatError, match="Isym = 0 .no symmetry. needs C planes from 0 round the circle"):
        parse_ldt(text, "probe.ldt")
    with pytest.raises(IESFormatError, match="expected a finite number"):
        parse_ldt(ldt_text(1, 1, 0.0, [0.0, 90.0], [[100.0, 50.0]], flux=float("nan")), "probe.ldt")
    with pytest.raises(IESFormatError, match="conversion factor"):
        parse_ldt(ldt_text(1, 1, 0.0, [0.0, 90.0], [[100.0, 50.0]], conversion=-1.0), "probe.ldt")


def test_photometric_text_in_utf8_with_a_byte_order_mark_and_bad_types(tmp_path):
    # A UTF-8 file with a byte-order mark before its first line had been "no TILT= line" (the
    # mark before TILT=) and its name garbled (read as Latin-1); Latin-1 files still read.
    text = _ies().replace("[LUMINAIRE] probe", "[LUMINAIRE] Größe")
    (tmp_path / "u.ies").write_bytes(b"\xef\xbb\xbf" + text.split("\n", 1)[1].encode("utf-8"))  # mark, then TILT=
    (tmp_path / "l.ies").write_bytes(text.encode("latin-1"))
    assert read_ies(tmp_path / "u.ies").candela.max() == 100.0
    assert read_ies(tmp_path / "l.ies").name == "Größe"
    with pytest.raises(InvalidInputError, match="takes the file's text"):
        parse_ies(text.encode())
    with pytest.raises(IESFormatError, match="number of vertical angles must be an integer >= 2"):
        parse_ies(_ies(header="1 1000 1.0 1 1 1 2 0.5 0.5 0.1", vert="0", cd="100"))


def test_sensor_and_work_plane_shapes_are_named():
    plates = pydynrad.scenes.parallel_plates(subdivisions=1)
    with pytest.raises(InvalidInputError, match=r"sensor points must have shape \(n, 3\)"):
        illuminance(
            plates,
            None,
            [1, 2],
            [0, 0, 1],
            lights=LuminaireLight((0.5, 0.5, 0.5), PhotometricDistribution.isotropic(1.0)),
        )
    from pydynrad.photometry import work_plane

    square = [[0, 0], [4, 0], [4, 3], [0, 3]]
    for up in (2.0, True):
        with pytest.raises(InvalidInputError, match="up .the axis the plane faces. must be an integer"):
            work_plane(square, 0.75, up=up)
    with pytest.raises(InvalidInputError, match="more than half the memory available"):
        work_plane(square, 0.75, spacing=1e-7)
    with pytest.raises(InvalidInputError, match="more than half the memory available"):
        work_plane([[0, 0], [1e300, 0], [1e300, 1e300]], 0.75)


def test_lm63_2019_generation_type_is_no_factor_and_1995_lamp_factor_is():
    """The field after the ballast factor multiplies the candela only before LM-63-2002 (the
    ballast-lamp factor): LM-63-2002 makes it "future use" and LM-63-2019 the file generation
    type, a code (1.10000: accredited laboratory), which had made the table 10% too bright."""
    body = "TILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1.10000 20\n0 45 90\n0\n1000 500 100\n"
    for first, factor in (
        ("IES:LM-63-2019\n[TEST] t\n", 1.0),
        ("IESNA:LM-63-2002\n", 1.0),
        ("IESNA:LM-63-1995\n", 1.1),
        ("IESNA91\n", 1.1),
        ("", 1.1),
    ):
        np.testing.assert_allclose(
            parse_ies(first + body).candela[0], np.array([1000.0, 500.0, 100.0]) * factor, rtol=1e-15
        )
    # A 1986 file's free text may start with the word Tilt: only TILT= ends the header.
    np.testing.assert_allclose(parse_ies("Tiltable wall washer\n" + body).candela[0], [1100.0, 550.0, 110.0])


def test_c_symmetries_the_reader_fills_or_refuses():
    """A 90-270 table whose mirror images miss C = 0 gets it by the circle's interpolation; a
    full circle one step short of 360 closes on C = 0, a wider gap is refused."""
    two = parse_ies("TILT=NONE\n1 1000 1 2 2 1 2 0 0 0\n1 1 0\n0 90\n90 270\n100 50 10 5\n")
    np.testing.assert_array_equal(two.c_angles, [0.0, 90.0, 270.0, 360.0])
    np.testing.assert_allclose(two.intensity([0.0, 180.0, 45.0], 0.0), [55.0, 55.0, 77.5])
    gap = "TILT=NONE\n1 1000 1 2 3 1 2 0 0 0\n1 1 0\n0 90\n0 90 200\n1 1 2 2 3 3\n"
    with pytest.raises(IESFormatError, match="0..200 are not a symmetry"):
        parse_ies(gap)
    short = parse_ies(gap.replace("0 90 200", "0 120 240"))
    np.testing.assert_allclose(short.intensity([300.0], 0.0), [2.0])  # halfway from C240 (3) to C360 = C0 (1)


def test_tilt_and_closed_forms_name_their_own_bad_values():
    body = "1 -1 1 3 1 1 2 0 0 0\n1 1 20\n0 45 90\n0\n1000 500 100\n"
    with pytest.raises(InvalidInputError, match="tilt .* one finite number"):
        parse_ies("TILT=NONE\n" + body, tilt=float("nan"))
    with pytest.raises(IESFormatError, match="tilt multiplying factors must be >= 0"):
        parse_ies("TILT=INCLUDE\n1\n2\n0 90\n-1 -1\n" + body)
    for bad in (200.0, 0.0, 1e-9, 7.0):
        with pytest.raises(InvalidInputError, match="lambertian step must divide 90"):
            PhotometricDistribution.lambertian(1000.0, step=bad)
    assert PhotometricDistribution.lambertian(1000.0, step=30.0).flux() == pytest.approx(math.pi * 1000.0, rel=0.03)
    with pytest.raises(InvalidInputError, match="flux quadrature size"):
        PhotometricDistribution.isotropic(1.0).flux(0)
    with pytest.raises(InvalidInputError, match="isotropic intensity"):
        PhotometricDistribution.isotropic("a")
    with pytest.raises(InvalidInputError, match="C = 360 must equal those at C = 0"):
        PhotometricDistribution([0, 180, 360], [0, 90], [[100, 100], [100, 100], [0, 0]])
    with pytest.raises(InvalidInputError, match="finite"):
        PhotometricDistribution.lambertian(10.0).intensity(np.nan, 10.0)


def test_ldt_counts_that_do_not_match_the_file_are_named():
    """Ng = 3 declared over five gamma angles and intensities: the values left after the table
    are named, not read as the wrong fields."""
    from pydynrad.lights.ldt import parse_ldt

    head = [
        "c",
        "1",
        "1",
        "1",
        "0",
        "3",
        "45",
        "r",
        "name",
        "n",
        "f",
        "d",
        *"200 0 100 180 0 0 0 0 0 100 85 1 0 1 1 LED 1000 3000K 1B 20".split(),
        *["0.5"] * 10,
        "0",
    ]
    good = "\n".join(head + "0 45 90".split() + "500 400 300".split()) + "\n\n"
    np.testing.assert_allclose(parse_ldt(good).candela[0], [500.0, 400.0, 300.0])
    with pytest.raises(IESFormatError, match="line 50: 4 line"):
        parse_ldt("\n".join(head + "0 45 90 135 180".split() + "500 400 300 0 0".split()))
    for bad in (b"x", None):
        with pytest.raises(InvalidInputError, match="parse_ldt takes the file's text"):
            parse_ldt(bad)
    for bad in (None, 5, b"/tmp/x"):
        with pytest.raises(InvalidInputError, match="must be a str or a path"):
            read_ies(bad)
