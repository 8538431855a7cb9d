"""progress=None means "after two seconds" everywhere; True and False force it."""

import pydynrad
from pydynrad.progress import shows_progress


def test_the_rule(monkeypatch, capsys):
    """tqdm's rules: None shows a bar after the delay on any stream, True at once."""
    assert shows_progress(True) and not shows_progress(False)
    assert shows_progress(None)  # not only on a terminal: tqdm's delay decides


def test_long_calls_follow_it(device, capsys, tmp_path):
    """The path tracer used to treat progress=None as False; walk and the stores as True."""
    s = pydynrad.scenes.parallel_plates(subdivisions=0)
    F = pydynrad.form_factors(s, resolution=8, device=device)
    B = pydynrad.solve(s, F, device=device).radiosity
    calls = {
        "path tracing": lambda p: pydynrad.pathtracer.path_trace_patches(s, spp=2, device=device, progress=p),
        "form factors R=8": lambda p: pydynrad.form_factors(s, resolution=8, device=device, progress=p),
        "multibounce": lambda p: pydynrad.multibounce(
            s, pydynrad.form_factors(s, resolution=8, device=device), device=device, progress=p
        ),
        "form factors": lambda p: pydynrad.compute_store(
            s, tmp_path / f"store-{p}", resolution=8, device=device, progress=p
        ),
        "solve N=": lambda p: pydynrad.solve(s, F, device=device, progress=p),
        "bake lightmap": lambda p: pydynrad.bake_lightmap(s, B, 2.0, device=device, progress=p),
    }
    for desc, call in calls.items():
        call(None)
        assert capsys.readouterr().err == "", desc
        call(True)
        assert desc in capsys.readouterr().err, desc
