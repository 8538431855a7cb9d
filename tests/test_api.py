"""The public API: the top-level names, and the names that moved into subpackages."""

import importlib

import pytest

import pydynrad


def test_all_is_short_and_resolves():
    assert len(pydynrad.__all__) <= 40
    assert len(set(pydynrad.__all__)) == len(pydynrad.__all__)
    for name in pydynrad.__all__:
        assert getattr(pydynrad, name) is not None


@pytest.mark.parametrize("name", sorted(pydynrad._MOVED))
def test_moved_name_still_served_with_a_warning(name):
    home = importlib.import_module(f"pydynrad.{pydynrad._MOVED[name]}")
    with pytest.warns(DeprecationWarning, match=f"pydynrad.{name} moved to pydynrad.{pydynrad._MOVED[name]}"):
        value = getattr(pydynrad, name)
    assert value is getattr(home, name)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        pydynrad.no_such_name  # noqa: B018
