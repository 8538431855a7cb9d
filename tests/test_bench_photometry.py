"""The photometry bench section at its tiny size: its tables hold what they say."""

import math

from bench import suite


def test_photometry_section_tiny(tmp_path, device):
    results, _ = suite.run_suite("tiny", ["photometry"], tmp_path, device=device, progress=False, strict=True)
    tables = {t["title"]: t for t in results["sections"]["photometry"]["tables"]}
    ((sensors, R, dt, per_s, mrays),) = tables["Sensor throughput"]["rows"]
    assert sensors == 16 and R == 16 and per_s == sensors / dt and math.isfinite(mrays)
    near = tables["Hemicube near an emitter"]["rows"]
    assert len(near) == 2 * 2  # two sensors x two distances at one resolution
    for label, d, _R, exact, hemi, err in near:
        assert err == abs(hemi - exact) / exact
        if d == 1.0 and label.startswith("below"):
            assert err < 0.01  # far below the centre even R = 16 is good: 0.2% observed
